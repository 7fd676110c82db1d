"""HG-DAgger (Kelly et al., 2019), the data collection of BC-Z: a trained policy acts, a scripted expert watches
and takes over when the policy drifts, and only the stretches the expert drives become new demonstrations.

The intervention rule. In the paper a human decides when to take over; here a fixed rule decides, so runs repeat:

- every step the expert computes its own action ``a_E`` beside the policy's ``a_P`` (both in the env's
  ``[-1, 1]`` action box) and their disagreement ``d = ||a_P - a_E||_2 / sqrt(A)`` (root mean square over the
  action's ``A`` components);
- the expert **takes over** when ``d > threshold`` on ``patience`` consecutive steps (the last of them is
  already its own: the policy drove the ones before);
- while the expert drives, the policy keeps proposing; the expert **hands back** when ``d <= threshold`` on
  ``patience`` consecutive steps (the policy would now do what the expert does);
- every step the expert drives is recorded with its action as the label, and each stretch of expert control
  becomes one episode of the new dataset. Steps the policy drives are never labelled (HG-DAgger's difference
  from DAgger, where the expert labels every visited state).

A round of HG-DAgger is then: ``taskrl demos dagger RUN --out NEW`` (this module), ``taskrl demos merge OLD NEW
--out ALL``, and training again on ``ALL`` (``benchmarks/hg_dagger.py`` runs the rounds).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.demos.dataset import Episode, _read_episodes, check_new_dataset_folder, dataset_card, write_dataset
from taskrl.demos.experts import demo_source
from taskrl.errors import ConfigError

__all__ = ["InterventionRule", "collect_interventions", "merge_datasets"]


@dataclasses.dataclass(frozen=True)
class InterventionRule:
    """When the scripted expert takes over from the policy and when it hands back (module docstring).

    Attributes:
        threshold: root-mean-square disagreement between the policy's and the expert's action (in the
            ``[-1, 1]`` box) above which the policy counts as drifting.
        patience: consecutive steps the disagreement must stay above (to take over) or at or below (to
            hand back) the threshold.
    """

    threshold: float = 0.3
    patience: int = 3

    def validate(self) -> None:
        if isinstance(self.threshold, bool) or not isinstance(self.threshold, (int, float)) or not self.threshold > 0:
            raise ConfigError("threshold", f"must be a number > 0 (got {self.threshold!r})")
        if isinstance(self.patience, bool) or not isinstance(self.patience, int) or self.patience < 1:
            raise ConfigError("patience", f"must be an integer >= 1 (got {self.patience!r})")


class _Gate:
    """Who drives each env copy, under an `InterventionRule`."""

    def __init__(self, n: int, rule: InterventionRule, device: torch.device) -> None:
        self.rule = rule
        self.expert = torch.zeros(n, dtype=torch.bool, device=device)  # the expert drives
        self.streak = torch.zeros(n, dtype=torch.long, device=device)

    def decide(self, policy_action: torch.Tensor, expert_action: torch.Tensor) -> torch.Tensor:
        """Update who drives from this step's two actions; returns the ``[n]`` mask of copies the expert drives now."""
        disagreement = (policy_action - expert_action).norm(dim=-1) / math.sqrt(policy_action.shape[-1])
        drifting = disagreement > self.rule.threshold
        toward_switch = torch.where(self.expert, ~drifting, drifting)
        self.streak = torch.where(toward_switch, self.streak + 1, torch.zeros_like(self.streak))
        switch = self.streak >= self.rule.patience
        self.expert ^= switch
        self.streak[switch] = 0
        return self.expert.clone()

    def episodes_ended(self, ended: torch.Tensor) -> None:
        self.expert[ended] = False
        self.streak[ended] = 0


def collect_interventions(
    run: tuple[Any, Any, Any],
    out: str | Path,
    *,
    run_name: str = "",
    episodes: int = 10,
    rule: InterventionRule | None = None,
    seed: int = 2,
    after_success: int = 10,
    progress: Callable[[int, int], Any] | None = None,
) -> dict[str, Any]:
    """Run a trained policy with its env family's scripted expert gating it (HG-DAgger) and write the expert's
    corrections as a dataset in ``out``; returns the card (with the counts of both drivers' steps).

    Args:
        run: ``(agent, config, spaces)`` of a run trained on a family with a scripted expert (``taskrl demos collect``
            lists them), as [`taskrl.loading.load_run`][taskrl.loading.load_run] gives it (on the device the policy runs on).
        run_name: what the card calls that run (its folder).
        out: the folder of the new dataset (``out/data``); nothing is written when the expert never took over.
        episodes: episodes per task, the policy and the expert sharing the control.
        rule: the intervention rule (default `InterventionRule`).
        seed: seed of the goals (keep it apart from the demonstrations' and the evaluation's).
        after_success: steps an episode goes on after its first success (as ``taskrl demos collect``).
        progress: ``(episodes done, episodes wanted)`` after every step.
    """
    from taskrl.training.evaluation import ActingPolicy

    rule = rule or InterventionRule()
    rule.validate()
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1 (got {episodes!r})")
    out = check_new_dataset_folder(out)
    agent, config, spaces = run
    if spaces.task_set is None:
        raise ConfigError(
            "run_dir", f"{run_name or 'the run'} was trained on {config.env}, which has no task set for a scripted expert"
        )
    source = demo_source(f"{config.env}:{','.join(spaces.task_set.names)}")
    view = getattr(config.env_settings, "policy_observation", None)  # the run's protocol (a hidden goal, say)
    policy = ActingPolicy(agent)
    started = time.perf_counter()
    # a policy that reads pictures is shown them at its run's size, and the corrections keep them (BC-Z's data is the
    # camera's): a dataset of corrections without pictures could not be merged with the pictures' demonstrations
    size = config.env_settings.image_size if getattr(agent, "image_shape", None) is not None else None
    env = source.make_env(spaces.task_set.names, 1, seed, after_success, **({"image_size": size} if size else {}))
    try:
        expert = source.expert(env)
        n, names = env.num_envs, [env.task_set.names[int(t)] for t in env.slot_tasks.tolist()]
        done = dict.fromkeys(env.task_set.names, 0)
        counts = {k: dict.fromkeys(env.task_set.names, 0) for k in ("policy_steps", "expert_steps", "interventions", "successes")}
        gate = _Gate(n, rule, env.device)
        stretches: list[Episode] = []
        open_rows: list[dict[str, list] | None] = [None] * n
        reached = [False] * n
        obs = env.reset(seed=seed)
        camera = size is not None and "image" in obs
        with torch.no_grad():
            while min(done.values()) < episodes:
                expert_action = expert(obs)
                seen = {**obs, "observation": view(obs["observation"])} if view is not None else obs
                policy_action = policy(seen)
                by_expert = gate.decide(policy_action, expert_action)
                action = torch.where(by_expert[:, None], expert_action, policy_action)
                next_obs, reward, terminated, truncated, info = env.step(action)
                ended = terminated | truncated
                states = obs["observation"].cpu().numpy()
                after = torch.where(ended[:, None], info["final_obs"]["observation"], next_obs["observation"]).cpu().numpy()
                labels, rewards = expert_action.cpu().numpy(), reward.cpu().numpy()
                success = info["is_success"].cpu().numpy().astype(bool)
                if camera:
                    pictures = obs["image"].cpu().numpy()
                    pictures_after = (
                        torch.where(ended[:, None, None, None], info["final_obs"]["image"], next_obs["image"]).cpu().numpy()
                    )
                for s in range(n):
                    counting = done[names[s]] < episodes
                    rows = open_rows[s]
                    if counting:
                        counts["expert_steps" if by_expert[s] else "policy_steps"][names[s]] += 1
                        reached[s] = reached[s] or bool(success[s])
                    if by_expert[s] and counting:
                        if rows is None:
                            rows = open_rows[s] = {"o": [], "a": [], "r": [], "s": [], "i": []}
                            counts["interventions"][names[s]] += 1
                        rows["o"].append(states[s]), rows["a"].append(labels[s])
                        rows["r"].append(rewards[s]), rows["s"].append(success[s])
                        if camera:
                            rows["i"].append(pictures[s])
                    if rows is not None and (not by_expert[s] or ended[s]):  # the stretch ends
                        # handed back: it ended in this step's state; the episode ended: in the final state
                        final = after[s] if by_expert[s] else states[s]
                        final_picture = (pictures_after[s] if by_expert[s] else pictures[s]) if camera else None
                        stretches.append(
                            Episode(
                                names[s],
                                np.stack([*rows["o"], final]),
                                np.stack(rows["a"]),
                                np.asarray(rows["r"], dtype=np.float32),
                                np.asarray(rows["s"], dtype=bool),
                                bool(terminated[s]) and bool(by_expert[s]),
                                np.stack([*rows["i"], final_picture]) if camera else None,
                            )
                        )
                        open_rows[s] = None
                    if ended[s]:
                        if counting:
                            done[names[s]] += 1
                            counts["successes"][names[s]] += int(reached[s])
                        reached[s] = False
                policy.episodes_ended(ended)
                gate.episodes_ended(ended)
                obs = next_obs
                if progress is not None:
                    progress(sum(min(v, episodes) for v in done.values()), episodes * len(done))
    finally:
        env.close()
    card = {
        "source": f"hg-dagger of {Path(run_name).name}",
        "expert": "scripted, intervening",
        "run": str(run_name),
        "checkpoint_step": agent.loaded_step,
        "rule": dataclasses.asdict(rule),
        "seed": seed,
        "after_success": after_success,
        "episodes_per_task": {k: sum(e.task == k for e in stretches) for k in done},  # stretches of expert control
        "episodes_with_policy": episodes,
        "success_rate_with_interventions": {k: v / episodes for k, v in counts["successes"].items()},
        **{k: v for k, v in counts.items() if k != "successes"},
        "expert_steps_total": sum(counts["expert_steps"].values()),
        "policy_steps_total": sum(counts["policy_steps"].values()),
        "collection_seconds": round(time.perf_counter() - started, 1),
    }
    if stretches:
        box = gym.spaces.Box(-1.0, 1.0, shape=stretches[0].actions.shape[1:], dtype=np.float32)
        write_dataset(out, stretches, [(t.name, t.description) for t in env.task_set], box, card, "taskrl/hg-dagger-v0")
    return card


def _dataset_kind(episodes: list[Episode]) -> dict[str, Any]:
    """What two datasets must share to be merged: the state's and the action's width, and the pictures' shape."""
    e = episodes[0]
    pictures = "none" if e.images is None else "x".join(str(n) for n in e.images.shape[1:])
    return {"state width": e.observations.shape[1], "action width": e.actions.shape[1], "pictures": pictures}


def merge_datasets(inputs: Sequence[str | Path], out: str | Path, max_steps: int | None = None) -> dict[str, Any]:
    """One dataset of every episode of ``inputs``, in order; with ``max_steps``, only the first episodes up to that
    many steps (the last one cut to fit), e.g. to give plain BC as many expert labels as HG-DAgger had."""
    if not inputs:
        raise ConfigError("datasets", "name one dataset or more to merge")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1):
        raise ConfigError("max_steps", f"must be an integer >= 1 (got {max_steps!r})")
    out = check_new_dataset_folder(out)
    tasks: dict[str, str] = {}
    episodes: list[Episode] = []
    cards = []
    first_kind = None
    for path in inputs:
        metadata, read, descriptions = _read_episodes(path)
        kind = _dataset_kind(read)
        if first_kind is not None and kind != first_kind:
            said = ", ".join(
                f"{k} {first_kind[k]} in {inputs[0]} but {kind[k]} in {path}" for k in kind if kind[k] != first_kind[k]
            )
            raise ConfigError("datasets", f"cannot merge datasets of different kinds: {said}")
        first_kind = first_kind or kind
        cards.append(metadata.get("card") or {})
        for name, text in descriptions.items():
            tasks.setdefault(name, text)
        episodes += read
    if max_steps is not None:
        kept, total = [], 0
        for e in episodes:
            if total >= max_steps:
                break
            take = min(len(e), max_steps - total)
            if take < len(e):
                pictures = None if e.images is None else e.images[: take + 1]
                e = Episode(
                    e.task, e.observations[: take + 1], e.actions[:take], e.rewards[:take], e.success[:take], False, pictures
                )
            kept.append(e)
            total += take
        episodes = kept
    first = cards[0]
    card = {
        **{k: first[k] for k in ("source", "splits", "after_success") if k in first},
        "merged_from": [str(p) for p in inputs],
        "episodes_per_task": {n: sum(e.task == n for e in episodes) for n in tasks},
        "steps": sum(len(e) for e in episodes),
    }
    box = gym.spaces.Box(-1.0, 1.0, shape=episodes[0].actions.shape[1:], dtype=np.float32)
    write_dataset(out, episodes, list(tasks.items()), box, card, "taskrl/merged-v0")
    return dataset_card(out)
