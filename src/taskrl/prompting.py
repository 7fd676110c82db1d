"""Evaluating a prompted policy on tasks it was not trained on: by their description, a paraphrase, or one demonstration.

A policy that reads a task *embedding* (behaviour cloning with language or demo input) can be told a
task it never trained on. `evaluate_prompted` builds an env of those tasks (the family's
``tasks_env``), gives the policy one context per task and runs the per-task evaluation:

- ``description``: the sentence embedding of the task's description;
- ``paraphrase``: of another wording of it, never seen in training (the family's ``task_sentences``);
- ``demo``: the demo encoder's embedding of one demonstration of the task (the dataset's first);

and two controls, for what a zero-shot figure owes to its prompt:

- ``none``: a null prompt (a zero context), the policy told nothing of the task;
- ``other-task``: each task prompted as another of the evaluated tasks (the next one in order: its
  description under language input, its demonstration under demo input).

``sentence=`` evaluates whatever task a free sentence names (``taskrl eval RUN --task "open the
drawer"``): the env runs the task whose known sentences are nearest to it (cosine of sentence
embeddings), and the policy is prompted with the sentence itself.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

import torch

from taskrl.envs.registry import env_family
from taskrl.errors import ConfigError
from taskrl.loading import load_run, per_task_intervals
from taskrl.training.evaluation import ActingPolicy
from taskrl.training.per_task import TooManyEpisodes, evaluate_per_task
from taskrl.wiring.parts import EVAL_SEED_OFFSET, env_request, use_run_threads

__all__ = ["PROMPTS", "evaluate_prompted", "nearest_task"]

PROMPTS = ("description", "paraphrase", "demo", "none", "other-task")
Prompt = Literal["description", "paraphrase", "demo", "none", "other-task"]


def nearest_task(sentence: str, sentences: dict[str, list[str]]) -> tuple[str, float]:
    """``(task name, cosine)`` of the task one of whose sentences is closest to ``sentence``."""
    from taskrl.conditioning.language import sentence_embeddings

    names = [n for n, said in sentences.items() for _ in said]
    known = sentence_embeddings([s for said in sentences.values() for s in said])
    query = sentence_embeddings([sentence])[0]
    scores = known @ query
    best = int(torch.argmax(scores))
    return names[best], float(scores[best])


def evaluate_prompted(
    run_dir: str | Path,
    tasks: list[str] | None = None,
    *,
    sentence: str | None = None,
    prompt: Prompt = "description",
    dataset: str | None = None,
    episodes: int = 50,
    seed: int | None = None,
    device: str = "cpu",
) -> dict[str, Any]:
    """Success per task of a prompted policy on ``tasks`` (default: the run's held-out tasks), or on the task
    ``sentence`` names.

    Args:
        run_dir: a run of a prompted algorithm (``--algo bc`` with language or demo input).
        tasks: task names of the run's env family.
        sentence: a free sentence instead of ``tasks``: the task it names is run, prompted with it.
        prompt: ``description``, ``paraphrase`` (the first other wording the family ships), ``demo``, or the
            controls ``none`` (a null prompt) and ``other-task`` (each task prompted as the next evaluated one).
        dataset: where demonstrations of the tasks are (``demo``; default the run's dataset).
        episodes: episodes per task.
        seed: evaluation seed (default the run's evaluation seed).
        device: where the networks go.

    Returns:
        as ``taskrl eval --json``: ``success_rate`` (mean over tasks) with ``success_ci95``, ``tasks``
        (each with its interval and the sentence it was prompted with), ``prompt``.
    """
    if prompt not in PROMPTS:
        raise ConfigError("prompt", f"unknown prompt {prompt!r}; allowed: {', '.join(PROMPTS)}")
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1 (got {episodes!r})")
    agent, config, _ = load_run(run_dir, device)
    use_run_threads(config)
    family = env_family(config.env)
    if family.tasks_env is None or family.task_sentences is None:
        raise ConfigError(
            "env", f"{config.env!r} cannot build tasks other than its own: prompted evaluation needs a multi-task family"
        )
    if not hasattr(agent, "prompt_with_descriptions"):
        raise ConfigError(
            "run_dir", f"{run_dir} was trained with --algo {config.algo}, which is not told its task by a prompt (use --algo bc)"
        )
    known = family.task_sentences(config.env_settings)
    matched = None
    if sentence is not None:
        if not isinstance(sentence, str) or not sentence.strip():
            raise ConfigError("task", "must be a sentence describing a task")
        name, score = nearest_task(sentence, known)
        matched, tasks, said = {"task": name, "cosine": score}, [name], [sentence]
    else:
        held = config.algo_settings.held_out() if hasattr(config.algo_settings, "held_out") else []
        tasks = list(tasks or held)
        if not tasks:
            raise ConfigError("held_out_tasks", "the run holds out no task: name tasks to evaluate (--tasks NAME,NAME)")
        unknown = [n for n in tasks if n not in known]
        if unknown:
            raise ConfigError("tasks", f"unknown task {unknown[0]!r} for {config.env}; allowed: {', '.join(known)}")
        if prompt == "other-task" and len(tasks) < 2:
            raise ConfigError("prompt", "other-task prompts each task as another evaluated task: name two tasks or more")
        if prompt == "paraphrase":
            missing = [n for n in tasks if len(known[n]) < 2]
            if missing:
                raise ConfigError("prompt", f"no paraphrase ships for {', '.join(missing)}")
            said = [known[n][1] for n in tasks]
        else:
            said = [known[n][0] for n in tasks]
        if prompt == "other-task":  # task i is told task i + 1's description
            said = said[1:] + said[:1]
    demo_input = getattr(agent, "demo_encoder", None) is not None
    if prompt == "none":
        agent.prompt_with_nothing(len(tasks))
        said = ["(null prompt)"] * len(tasks)
    elif prompt == "demo" or (prompt == "other-task" and demo_input):
        from taskrl.demos.dataset import read_demonstrations
        from taskrl.demos.sampling import prompt_frames

        shown = tasks[1:] + tasks[:1] if prompt == "other-task" else tasks
        demos = read_demonstrations(dataset or config.algo_settings.dataset, agent.device).select_tasks(shown)
        demos = demos.as_seen_under(config.env_settings)
        agent.prompt_with_demos(prompt_frames(demos, agent.config.demo_frames))  # each task's first demonstration
        if prompt == "other-task":
            said = [f"one demonstration of {name}" for name in shown]
    else:
        agent.prompt_with_descriptions(said)
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else seed
    request = dataclasses.replace(env_request(config, agent.device, evaluation=True, seed=seed), eval_episodes=episodes)
    env = family.tasks_env(config.env_settings, request, tasks)
    try:
        criterion = family.success_criterion(config.env_settings)
        try:
            result = evaluate_per_task(ActingPolicy(agent), env, episodes, seed, success=criterion)
        except TooManyEpisodes as error:
            raise ConfigError("episodes", f"{error}: use --episodes with fewer") from None
    finally:
        env.close()
        agent.reset_prompts()
    out_tasks, interval = per_task_intervals(result["tasks"])
    for row, text in zip(out_tasks.values(), said):
        row["prompt"] = "one demonstration" if prompt == "demo" else text
    return {
        "success_rate": result["mean_success_rate"],
        "success_ci95": interval,
        "episodes": episodes,
        "prompt": "sentence" if sentence is not None else prompt,
        "tasks": out_tasks,
        "checkpoint_step": agent.loaded_step,
        **({"matched": matched} if matched else {}),
    }
