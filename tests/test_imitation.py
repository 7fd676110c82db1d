"""Multi-task imitation: demonstration datasets, stratified batches, the BC agent, prompted and held-out evaluation."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import taskrl
from helpers import cli, small_run
from taskrl.agents.bc import BCAgent, BCConfig
from taskrl.agents.spec import AgentInputs
from taskrl.conditioning.networks import ConditioningConfig, TaskConditioning
from taskrl.conditioning.task_encoders import LanguageTaskEncoder
from taskrl.demos.collect import collect_demos
from taskrl.demos.dataset import Episode, dataset_card, read_demonstrations, write_dataset
from taskrl.demos.sampling import DemoSampler
from taskrl.errors import ConfigError
from taskrl.prompting import evaluate_prompted

BOX = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)


def _episode(task: str, length: int, start: float) -> Episode:
    """Recognisable numbers: state row t is start + t, action row t is -(start + t)."""
    t = np.arange(length + 1, dtype=np.float32)[:, None]
    obs = np.concatenate([start + t, start + t], axis=1)
    return Episode(task, obs, -obs[:-1], np.zeros(length, np.float32), np.ones(length, bool), True)


@pytest.fixture(scope="module")
def point_demos(tmp_path_factory):
    """20 scripted demonstrations of each multi-task PointReach region."""
    out = tmp_path_factory.mktemp("demos") / "pointreach-mt"
    collect_demos("pointreach-mt", 20, out, seed=3)
    return out


# ---------------------------------------------------------------------- datasets
def test_dataset_round_trip_keeps_episodes_boundaries_and_tasks(tmp_path):
    episodes = [_episode("a", 3, 0.0), _episode("b", 5, 100.0), _episode("a", 2, 200.0)]
    write_dataset(tmp_path / "d", episodes, [("a", "Do a."), ("b", "Do b.")], BOX, {"source": "test"})
    demos = read_demonstrations(tmp_path / "d")
    assert demos.task_names == ("a", "b") and demos.descriptions == ("Do a.", "Do b.")
    assert demos.lengths.tolist() == [3, 5, 2] and demos.starts.tolist() == [0, 3, 8]
    assert demos.episode_tasks.tolist() == [0, 1, 0]
    assert demos.tasks.tolist() == [0] * 3 + [1] * 5 + [0] * 2
    obs, actions = demos.episode(1)
    assert obs[:, 0].tolist() == [100.0 + t for t in range(5)]  # the final state is not a training row
    assert torch.equal(actions, -obs)
    import os

    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "d" / "data").stat().st_mode & 0o777 == 0o777 & ~umask  # like any folder the user makes
    card = dataset_card(tmp_path / "d")
    assert card["card"] == {"source": "test"} and card["total_episodes"] == 3 and card["total_steps"] == 10
    # Minari itself reads it, with each episode's task in its metadata
    import minari

    data = minari.MinariDataset(tmp_path / "d" / "data")
    assert data.total_episodes == 3
    first = next(data.iterate_episodes())
    assert first.observations["observation"].shape == (4, 2) and first.actions.shape == (3, 2)
    assert [m["task"] for m in data.storage.get_episode_metadata([0, 1, 2])] == ["a", "b", "a"]


def test_select_and_drop_tasks_keep_the_right_rows(tmp_path):
    episodes = [_episode("a", 3, 0.0), _episode("b", 5, 100.0), _episode("c", 2, 200.0)]
    write_dataset(tmp_path / "d", episodes, [("a", "A."), ("b", "B."), ("c", "C.")], BOX, {})
    demos = read_demonstrations(tmp_path / "d")
    picked = demos.select_tasks(["c", "a"])  # an env's order: c is task 0 now
    assert picked.task_names == ("c", "a") and picked.episode_tasks.tolist() == [1, 0]
    assert picked.episode(1)[0][0, 0].item() == 200.0
    dropped = demos.without_tasks(["b"])  # indices unchanged: a is 0 and c is 2
    assert dropped.episode_tasks.tolist() == [0, 2] and dropped.num_steps == 5
    with pytest.raises(ConfigError, match="no demonstrations of d"):
        demos.select_tasks(["a", "d"])


def test_collection_resumes_and_keeps_the_episodes_it_had(tmp_path):
    out = tmp_path / "demos"

    class Stop(Exception):
        pass

    def stop_early(kept, wanted):
        if kept >= 12:
            raise Stop

    with pytest.raises(Stop):
        collect_demos("pointreach-mt", 10, out, seed=5, copies=2, flush_seconds=0.0, progress=stop_early)
    assert not (out / "data").exists() and list((out / "parts").glob("part-*.npz"))
    from taskrl.demos.collect import _read_parts

    before = _read_parts(out / "parts")
    assert len(before) >= 12
    with pytest.raises(ConfigError, match="other settings"):  # resuming with other settings would mix datasets
        collect_demos("pointreach-mt", 10, out, seed=6, copies=2)
    card = collect_demos("pointreach-mt", 10, out, seed=5, copies=2)
    assert card["total_episodes"] == 50 and not (out / "parts").exists()
    demos = read_demonstrations(out)
    firsts = {tuple(np.round(demos.episode(e)[0][0].numpy(), 6)) for e in range(demos.num_episodes)}
    kept = [e for e in before if tuple(np.round(e.observations[0], 6)) in firsts]
    per_task = {}
    for e in before:
        per_task[e.task] = per_task.get(e.task, 0) + 1
    # every episode collected before the interruption is in the dataset (up to 10 per task)
    assert len(kept) == sum(min(v, 10) for v in per_task.values())
    with pytest.raises(ConfigError, match="already holds a dataset"):
        collect_demos("pointreach-mt", 10, out)


def test_scripted_point_demonstrations_succeed_and_label_the_expert(point_demos):
    card = dataset_card(point_demos)["card"]
    assert card["episodes_per_task"] == dict.fromkeys(["top-left", "top-right", "bottom-left", "bottom-right", "centre"], 20)
    demos = read_demonstrations(point_demos)
    from taskrl.envs.multitask_point import DEFAULT_REGIONS

    centres = torch.tensor([c for _, _, c in DEFAULT_REGIONS])
    expected = ((centres[demos.tasks] - demos.observations) / 0.1).clamp(-1, 1)
    assert torch.allclose(demos.actions, expected, atol=1e-5)


def test_dart_noise_changes_what_runs_not_the_labels(tmp_path):
    collect_demos("pointreach-mt", 4, tmp_path / "noisy", seed=2, noise_std=0.5)
    demos = read_demonstrations(tmp_path / "noisy")
    from taskrl.envs.multitask_point import DEFAULT_REGIONS

    centres = torch.tensor([c for _, _, c in DEFAULT_REGIONS])
    labels = ((centres[demos.tasks] - demos.observations) / 0.1).clamp(-1, 1)
    assert torch.allclose(demos.actions, labels, atol=1e-5)  # the expert's action at each visited state
    obs, actions = demos.episode(0)
    moved = (obs[1:] - obs[:-1]) / 0.1
    assert not torch.allclose(moved, actions[:-1], atol=1e-3)  # but the executed actions were perturbed


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_metaworld_experts_collect_successful_episodes(tmp_path):
    card = collect_demos("reach,drawer-open", 2, tmp_path / "mw", seed=1, after_success=5)
    assert card["card"]["episodes_per_task"] == {"reach": 2, "drawer-open": 2}
    demos = read_demonstrations(tmp_path / "mw")
    assert demos.observations.shape[1] == 39 and demos.actions.shape[1] == 4
    import minari

    for e, episode in enumerate(minari.MinariDataset(tmp_path / "mw" / "data").iterate_episodes()):
        first = int(np.argmax(episode.infos["success"]))
        assert episode.infos["success"][first] and demos.lengths[e] == first + 1 + 5  # 5 steps kept after the first success


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_hidden_goal_run_trains_and_is_prompted_on_demonstrations_with_the_goal_hidden(tmp_path, monkeypatch):
    """A demo-prompted run with the goal hidden sees prompt demonstrations with the goal hidden too. Mutation:
    deleting the line of ``prompting.py`` that shows prompt demonstrations as the run sees them fails."""
    from taskrl.agents.bc import BCAgent
    from taskrl.envs.meta_world import MetaWorldSettings
    from taskrl.prompting import evaluate_prompted

    collect_demos("mt10", 1, tmp_path / "mw", seed=1, after_success=0)
    demos = read_demonstrations(tmp_path / "mw")
    seen = demos.as_seen_under(MetaWorldSettings(hidden_goal=True)).observations
    assert demos.observations[:, 36:39].abs().sum() > 0 and seen[:, 36:39].abs().sum() == 0
    assert torch.equal(seen[:, :36], demos.observations[:, :36])
    assert torch.equal(demos.as_seen_under(MetaWorldSettings()).observations, demos.observations)
    run = small_run(
        "bc-mt10-demo",
        tmp_path / "run",
        dataset=str(tmp_path / "mw"),
        hidden_goal=True,
        total_steps=20,
        eval_interval=10**6,
        eval_episodes=1,
        max_episode_steps=5,
    )
    normaliser = run.agent.inputs.normalize
    assert normaliser.mean[36:39].abs().sum() == 0 and normaliser.mean[:3].abs().sum() > 0  # fit on what the policy sees
    prompts = []
    prompt = BCAgent.prompt_with_demos
    monkeypatch.setattr(BCAgent, "prompt_with_demos", lambda agent, frames: prompts.append(frames) or prompt(agent, frames))
    result = evaluate_prompted(tmp_path / "run", tasks=["reach"], prompt="demo", episodes=1)
    assert result["tasks"]["reach"]["episodes"] == 1
    assert len(prompts) == 1 and prompts[0][..., 36:39].abs().sum() == 0 and prompts[0][..., :3].abs().sum() > 0


# ---------------------------------------------------------------------- sampling
def test_stratified_sampling_balances_tasks_and_masks_chunks(tmp_path):
    episodes = [_episode("big", 50, 1000.0 * i) for i in range(10)] + [_episode("small", 4, 99_000.0)]
    write_dataset(tmp_path / "d", episodes, [("big", "B."), ("small", "S.")], BOX, {})
    demos = read_demonstrations(tmp_path / "d")  # 500 steps of one task, 4 of the other
    sampler = DemoSampler(demos, chunk=3, frames=4)
    g = torch.Generator().manual_seed(0)
    batch = sampler.sample(20_000, g)
    share = (batch.obs["task"] == 1).float().mean().item()
    assert abs(share - 0.5) < 0.02
    # labels: the next actions of the same episode, masked past its end
    state = batch.obs["observation"][:, 0]
    for h in range(3):
        inside = batch.mask[:, h] > 0
        assert torch.allclose(batch.actions[inside, h, 0], -(state[inside] + h))
    small = batch.obs["task"] == 1
    last = small & (state == 99_003.0)  # the small episode's last step: only h = 0 exists
    assert last.any() and (batch.mask[last, 1:] == 0).all()
    # prompts: frames of a demonstration of the same task, first to last step
    assert (batch.demo[small][:, 0, 0] == 99_000.0).all() and (batch.demo[small][:, -1, 0] == 99_003.0).all()


# ---------------------------------------------------------------------- the agent
def _bc_agent(demos, **settings) -> BCAgent:
    table = torch.nn.functional.normalize(torch.randn(5, 16, generator=torch.Generator().manual_seed(1)), dim=1)
    conditioning = TaskConditioning(LanguageTaskEncoder(table), ConditioningConfig(architecture="film"))
    inputs = AgentInputs(("observation",), 2, BOX)
    return BCAgent(inputs, BCConfig(hidden_sizes=(64, 64), **settings), "cpu", conditioning)


def test_the_state_normaliser_is_fit_on_the_training_tasks_only(point_demos):
    demos = read_demonstrations(point_demos)
    agent = _bc_agent(demos, held_out_tasks="centre")
    agent.use_dataset(demos)
    training = demos.without_tasks(["centre"]).observations
    assert torch.allclose(agent.inputs.normalize.mean, training.mean(0), atol=1e-5)
    assert not torch.allclose(agent.inputs.normalize.mean, demos.observations.mean(0), atol=1e-3)


@pytest.mark.slow
def test_language_regression_pulls_each_demo_embedding_to_its_task(point_demos):
    torch.manual_seed(0)
    demos = read_demonstrations(point_demos)
    agent = _bc_agent(demos, task_input="demo", embedding_noise=0.0, demo_frames=8)
    sampler = agent.use_dataset(demos)
    g = torch.Generator().manual_seed(0)
    losses = [agent.update(sampler.sample(128, g))["language_loss"].item() for _ in range(300)]
    assert np.mean(losses[-20:]) < 0.5 * np.mean(losses[:20])
    with torch.no_grad():
        z = torch.nn.functional.normalize(agent.training_contexts(), dim=1)
    cos = z @ agent.task_encoder.table.T  # [demo of task i, language of task j]
    assert (cos.argmax(dim=1) == torch.arange(5)).all()  # each demo is closest to its own task's sentence
    assert (cos.diagonal() > 0.8).all()


def test_temporal_ensembling_averages_the_chunks_that_cover_a_step():
    agent = _bc_agent(None, chunk=3, ensemble_decay=0.0)
    first = torch.tensor([[[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]])
    second = torch.tensor([[[5.0, 5.0], [6.0, 6.0], [7.0, 7.0]]])
    assert torch.equal(agent._ensembled(first), torch.tensor([[1.0, 1.0]]))
    assert torch.equal(agent._ensembled(second), torch.tensor([[3.5, 3.5]]))  # (2 + 5) / 2
    agent.episodes_ended(torch.tensor([True]))  # a new episode forgets the old predictions
    assert torch.equal(agent._ensembled(second), torch.tensor([[5.0, 5.0]]))


def test_bc_config_refuses_bad_settings():
    for bad, field in ((dict(loss="l2"), "loss"), (dict(chunk=0), "chunk"), (dict(language_prompts=2.0), "language_prompts")):
        with pytest.raises(ConfigError) as error:
            BCConfig(**bad).validate()
        assert error.value.field == field


# ---------------------------------------------------------------------- runs
@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("extra", [{}, {"chunk": 4, "loss": "gaussian"}])
def test_bc_learns_multitask_pointreach_from_demonstrations(point_demos, tmp_path, extra):
    """A random policy ends in its task's region about 1% of the time; cloning the scripted expert, >= 0.9."""
    run = small_run("pointreach-mt-bc", tmp_path / "run", dataset=str(point_demos), **extra)
    assert run.metrics["success_rate"] >= 0.9
    assert run.metrics["env_steps"] == 0 and run.metrics["updates"] == 2_000  # offline: updates are the axis
    again = taskrl.evaluate_run(tmp_path / "run", episodes=20)
    assert again["success_rate"] >= 0.9 and again["checkpoint_unit"] == "gradient updates"
    from taskrl.export import export_policy

    policy = taskrl.load_policy(export_policy(tmp_path / "run", tmp_path / "policy"))
    action = policy.predict({"observation": np.array([0.5, 0.5], np.float32), "task": 3})  # bottom-right: down
    assert action.shape == (2,) and action[1] < -0.5


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_held_out_tasks_are_not_trained_on_and_are_evaluated_by_prompt(point_demos, tmp_path):
    run = small_run(
        "pointreach-mt-bc",
        tmp_path / "run",
        dataset=str(point_demos),
        held_out_tasks="centre",
        task_input="demo",
        task_encoder="language",
        total_steps=300,
        eval_interval=300,
    )
    from taskrl.run import build

    parts = build(run.config)
    try:
        batch = parts.sampler.sample(5_000, torch.Generator().manual_seed(0))
        assert (batch.obs["task"] != 4).all()  # centre (task 4) is never imitated
    finally:
        parts.close()
    for prompt in ("description", "paraphrase", "demo"):
        result = evaluate_prompted(tmp_path / "run", prompt=prompt, episodes=5)
        assert list(result["tasks"]) == ["centre"] and result["tasks"]["centre"]["episodes"] == 5
        assert 0.0 <= result["success_rate"] <= 1.0
    said = evaluate_prompted(tmp_path / "run", sentence="Go to the middle.", episodes=2)
    assert said["matched"]["task"] == "centre" and said["tasks"]["centre"]["prompt"] == "Go to the middle."


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_zero_shot_controls_fail_where_the_prompt_carries_the_task(point_demos, tmp_path, monkeypatch):
    """On tasks it trained on, a language-prompted policy succeeds by description; prompted with nothing, or as
    another task, it goes elsewhere: the controls a zero-shot figure is read against, on the description's own
    episodes. Mutation: the controls evaluated on ``seed + 7`` (other start states) fails."""
    import taskrl.prompting as prompting

    starts = []
    evaluate = prompting.evaluate_per_task

    def recording(policy, env, *args, **kwargs):
        reset = env.reset
        env.reset = lambda *a, **k: starts.append(reset(*a, **k)) or starts[-1]
        return evaluate(policy, env, *args, **kwargs)

    monkeypatch.setattr(prompting, "evaluate_per_task", recording)
    small_run("pointreach-mt-bc", tmp_path / "run", dataset=str(point_demos), task_encoder="language")
    tasks = ["top-left", "top-right", "bottom-left", "bottom-right"]
    told = evaluate_prompted(tmp_path / "run", tasks=tasks, prompt="description", episodes=10)
    other = evaluate_prompted(tmp_path / "run", tasks=tasks, prompt="other-task", episodes=10)
    nothing = evaluate_prompted(tmp_path / "run", tasks=tasks, prompt="none", episodes=10)
    assert told["success_rate"] >= 0.9
    assert other["success_rate"] <= 0.1 and nothing["success_rate"] <= 0.5
    assert other["tasks"]["top-left"]["prompt"] == told["tasks"]["top-right"]["prompt"]  # told the next task
    assert nothing["tasks"]["top-left"]["prompt"] == "(null prompt)"
    assert len(starts) == 3  # the controls start where the description's episodes start
    for control in starts[1:]:
        assert all(torch.equal(control[k], starts[0][k]) for k in starts[0])
    with pytest.raises(ConfigError, match="name two tasks or more"):
        evaluate_prompted(tmp_path / "run", tasks=["top-left"], prompt="other-task", episodes=1)


def test_a_sentence_names_the_meta_world_task_it_describes():
    from taskrl.envs.meta_world import METAWORLD_DESCRIPTIONS, METAWORLD_PARAPHRASES
    from taskrl.prompting import nearest_task

    known = {n: [d, *METAWORLD_PARAPHRASES.get(n, ())] for n, d in METAWORLD_DESCRIPTIONS.items()}
    for sentence, task in (
        ("open the drawer", "drawer-open"),
        ("close the window", "window-close"),
        ("put the lid on the box", "box-close"),
    ):
        assert nearest_task(sentence, known)[0] == task


@pytest.mark.slow
def test_prompting_a_one_hot_policy_is_refused(point_demos, tmp_path):
    small_run("pointreach-mt-bc", tmp_path / "run", dataset=str(point_demos), total_steps=10)
    with pytest.raises(ConfigError, match="language embeddings"):
        evaluate_prompted(tmp_path / "run", tasks=["centre"], episodes=1)
    with pytest.raises(ConfigError, match="unknown task 'nowhere'"):
        evaluate_prompted(tmp_path / "run", tasks=["nowhere"], episodes=1)
    with pytest.raises(ConfigError, match="holds out no task"):
        evaluate_prompted(tmp_path / "run", episodes=1)
    done = cli("eval", str(tmp_path / "run"), "--held-out", "--task", "go left")
    assert done.returncode == 2 and "choose one of --held-out, --tasks and --task" in done.stderr


@pytest.mark.slow
def test_cli_demos_and_bad_input_are_one_line(point_demos, tmp_path):
    info = cli("demos", "info", str(point_demos), "--json")
    assert info.returncode == 0 and json.loads(info.stdout)["total_episodes"] == 100
    for args, needle in (
        (("demos", "collect", "nowhere-task", "--out", str(tmp_path / "x")), "SOURCE unknown Meta-World task"),
        (("demos", "info", str(tmp_path)), "holds no dataset"),
        (("train", "pointreach-mt-bc", "--dataset", str(tmp_path / "missing"), "--out", str(tmp_path / "r")), "--dataset"),
        (("train", "pointreach-mt-bc", "--chunk", "0", "--out", str(tmp_path / "r")), "--chunk must be in 1..100"),
    ):
        done = cli(*args)
        assert done.returncode == 2, done.stderr
        assert len(done.stderr.strip().splitlines()) == 1 and needle in done.stderr, done.stderr
    assert not (tmp_path / "r").exists()  # a refused run leaves no directory


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_ending_evaluation_episodes_at_success_keeps_every_outcome():
    """Meta-World counts success at any step: stopping at it changes how long evaluation takes, not what it finds."""
    from taskrl.envs.meta_world import MetaWorldSettings, metaworld_expert
    from taskrl.envs.registry import env_family
    from taskrl.envs.spec import EnvRequest
    from taskrl.training.per_task import evaluate_per_task

    family = env_family("mt1")
    results = []
    for until_success in (False, True):
        settings = MetaWorldSettings(task="reach", max_episode_steps=150, eval_until_success=until_success)
        env = family.make(settings, EnvRequest(num_envs=1, seed=0, device=torch.device("cpu"), evaluation=True, eval_episodes=8))
        try:
            expert = metaworld_expert(env)
            # a deterministic expert that gives up on half of the goals (a function of the state alone)
            biased = lambda obs, expert=expert: expert(obs) * (obs["observation"][:, 36:37] > 0.0)
            results.append(evaluate_per_task(biased, env, 8, seed=0, success="any")["tasks"]["reach"])
        finally:
            env.close()
    full, short = results
    assert short["success_rate"] == full["success_rate"] == 0.5  # the same half of the goals, both ways
    assert short["mean_length"] < full["mean_length"] == 150
