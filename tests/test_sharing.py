"""Data sharing between tasks: task reward functions, the strategies, datasets, CQL, the offline loop."""

from __future__ import annotations

import csv
import json
import math

import pytest
import torch

import taskrl
from helpers import small_run
from taskrl.agents.dqn import DQNAgent, DQNConfig
from taskrl.agents.sac import SACAgent, SACConfig
from taskrl.checkpoint import latest_checkpoint
from taskrl.config import TrainConfig
from taskrl.envs.grid_tasks import GRID_TASKS, GridTasks
from taskrl.envs.point_tasks import POINT_TASKS, PointTasks
from taskrl.errors import ConfigError
from taskrl.overrides import with_overrides
from taskrl.plan import validate
from taskrl.replay import EpisodeReplay, Episodes, HindsightRelabeler
from taskrl.replay.batch import Batch
from taskrl.sharing import SHARING_STRATEGIES, SharingConfig, TaskSharing, collect_task_datasets
from taskrl.sharing.builtin import ConservativeSettings, HIPISettings, RandomSettings
from taskrl.sharing.datasets import random_actions

ENVS = [GridTasks, PointTasks]


def filled_replay(env_cls, steps: int = 300, seed: int = 0, weights=None, num_envs: int = 12):
    """A replay of random-action episodes of ``env_cls`` and the env that made them."""
    env = env_cls(num_envs=num_envs, seed=seed, task_weights=weights)
    replay = EpisodeReplay(
        env.single_observation_space, env.single_action_space, env.horizon * 2_000, num_envs=num_envs, horizon=env.horizon
    )
    generator = torch.Generator().manual_seed(seed)
    obs = env.reset(seed=seed)
    replay.start(obs)
    for _ in range(steps):
        action = random_actions(env.single_action_space, num_envs, generator, env.device)
        next_obs, reward, terminated, truncated, info = env.step(action)
        replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
        obs = next_obs
    return env, replay


@pytest.mark.parametrize("env_cls", ENVS)
def test_reward_under_another_task_equals_the_env_reward_for_that_task(env_cls):
    """r_j(s, a, s') scored from a transition collected under task i equals what the env gives when
    the same state and action are stepped with task j."""
    env = env_cls(num_envs=64, seed=1)
    obs = env.reset(seed=1)
    generator = torch.Generator().manual_seed(1)
    checked = 0
    for _ in range(40):
        action = random_actions(env.single_action_space, 64, generator, env.device)
        position, task = env.position.clone(), env.task.clone()
        next_obs, reward, terminated, _, info = env.step(action)
        for j in range(env.num_tasks):
            twin = env_cls(num_envs=64, seed=2)
            twin.reset(seed=2)
            twin.position, twin.task = position.clone(), torch.full_like(task, j)
            _, twin_reward, twin_terminated, _, _ = twin.step(action)
            task_j = torch.full_like(task, j)
            assert torch.equal(env.task_reward(obs, action, info["final_obs"], task_j), twin_reward)
            assert torch.equal(env.task_terminated(info["final_obs"], task_j), twin_terminated)
            checked += int(twin_reward.sum())
        assert torch.equal(env.task_reward(obs, action, info["final_obs"], task), reward)  # its own task too
        obs = next_obs
    assert checked > 0  # some transitions do solve some task


def test_hazard_ends_the_avoid_task_unsolved():
    env = GridTasks(num_envs=1, task_sampling="fixed", seed=0)
    env.reset(seed=0)
    avoid = [t.name for t in GRID_TASKS].index("top-left-avoid")
    env.task[:] = avoid
    env.position[:] = torch.tensor([[4.0, 3.0]])
    _, reward, terminated, truncated, info = env.step(torch.tensor([3]))  # left, onto the middle column
    assert bool(terminated[0]) and not bool(info["is_success"][0]) and float(reward[0]) == 0.0


@pytest.mark.parametrize("env_cls", ENVS)
def test_low_data_tasks_get_their_share_of_episodes(env_cls):
    weights = [1.0] * 5 + [0.1]
    env = env_cls(num_envs=4_000, seed=0, task_weights=weights)
    env.reset(seed=0)
    share = torch.bincount(env.task, minlength=6).float() / 4_000
    assert share[5].item() == pytest.approx(0.1 / 5.1, abs=0.006)
    assert share[:5].min().item() > 0.17


@pytest.mark.parametrize("fraction", [0.25, 0.5, 1.0])
def test_sharing_fractions_match_the_configuration(fraction):
    env, replay = filled_replay(GridTasks)
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing="all", share_fraction=fraction))
    generator = torch.Generator().manual_seed(0)
    batch = sharing(240, generator)  # 40 rows of each task
    per = 40
    source = replay.observation_at("task", batch.episode, 0)
    for j in range(env.num_tasks):
        rows = batch.obs["task"] == j
        assert int(rows.sum()) == per
        assert int((source[rows] != j).sum()) == round(fraction * per)
    metrics = sharing.metrics(env.task_set.names)
    assert metrics["shared_fraction"] == pytest.approx(round(fraction * per) / per)
    assert sum(metrics[f"from/{n}"] for n in env.task_set.names) == pytest.approx(1.0)


def test_none_shares_nothing_and_every_row_is_its_own_tasks():
    env, replay = filled_replay(GridTasks)
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing="none"))
    batch = sharing(256, torch.Generator().manual_seed(0))
    assert torch.equal(replay.observation_at("task", batch.episode, 0), batch.obs["task"])
    assert torch.equal(batch.reward, replay.gather(batch.episode, batch.step).reward)
    assert sharing.metrics(env.task_set.names)["shared_fraction"] == 0.0


@pytest.mark.parametrize("strategy", [name for name, spec in SHARING_STRATEGIES.items() if spec.shares])
def test_shared_rows_are_scored_under_their_new_task(strategy):
    env, replay = filled_replay(PointTasks)
    q = lambda obs, action: -(action.float() - 0.5).square().sum(-1)  # noqa: E731
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing=strategy), q_value=q)
    batch = sharing(300, torch.Generator().manual_seed(3))
    expected = env.task_reward(batch.obs, batch.action, batch.next_obs, batch.obs["task"])
    source = replay.observation_at("task", batch.episode, 0)
    shared = source != batch.obs["task"]
    assert bool(shared.any())
    assert torch.equal(batch.next_obs["task"], batch.obs["task"])
    if SHARING_STRATEGIES[strategy].zero_reward:
        assert torch.all(batch.reward[shared] == 0) and not bool(batch.terminated[shared].any())
        assert torch.equal(batch.reward[~shared], expected[~shared])
    else:
        assert torch.equal(batch.reward, expected)
        assert torch.equal(batch.terminated, env.task_terminated(batch.next_obs, batch.obs["task"]))


def test_success_shares_exactly_the_episodes_that_pass_the_success_test():
    env, replay = filled_replay(GridTasks, steps=400)
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing="success", share_fraction=1.0))
    source = replay.first_observations("task").long()
    weights = sharing.shared_weights(source, None)
    # brute force: episode e of task i != j passes j's test at some stored step
    for e in replay.stored_episodes().tolist():
        n = int(replay.length[e])
        next_obs = replay.gather(*replay.episode_steps(torch.tensor([e]))).next_obs
        for j in range(env.num_tasks):
            passes = bool(env.task_success(next_obs, torch.full((n,), j)).any())
            assert bool(weights[j, e] > 0) == (passes and int(source[e]) != j)
    # and the shared rows of a batch come from such episodes only
    batch = sharing(600, torch.Generator().manual_seed(0))
    shared = source[batch.episode] != batch.obs["task"]
    assert bool(shared.any())
    assert torch.all(weights[batch.obs["task"][shared], batch.episode[shared]] > 0)


def test_mtopt_shares_successes_and_failures_half_and_half_per_task():
    """Against a brute-force success test: of each task's shared rows, half from other tasks' episodes that pass
    its success test somewhere and half from those that do not (where it has both)."""
    env, replay = filled_replay(GridTasks, steps=400)
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing="mtopt", share_fraction=1.0))
    source = replay.first_observations("task").long()
    passes = torch.zeros(replay.episode_slots, env.num_tasks, dtype=torch.bool)
    for e in replay.stored_episodes().tolist():
        next_obs = replay.gather(*replay.episode_steps(torch.tensor([e]))).next_obs
        for j in range(env.num_tasks):
            passes[e, j] = bool(env.task_success(next_obs, torch.full((int(replay.length[e]),), j)).any())
    batch = sharing(6000, torch.Generator().manual_seed(0))
    task = batch.obs["task"].long()
    shared = source[batch.episode] != task
    balanced = 0
    for j in range(env.num_tasks):
        rows = shared & (task == j)
        others = (source != j) & (replay.length > 0)
        if not bool((passes[:, j] & others).any()) or not bool((~passes[:, j] & others).any()):
            continue
        share = passes[batch.episode[rows], j].float().mean().item()
        assert abs(share - 0.5) < 0.08, (j, share)  # ~1000 rows a task: 0.5 +- 5 standard errors
        balanced += 1
    assert balanced >= 2  # the test saw tasks with both kinds of episode


def test_random_draws_from_k_other_tasks_per_batch():
    env, replay = filled_replay(GridTasks)
    sharing = TaskSharing(
        replay,
        env,
        env.num_tasks,
        SharingConfig(sharing="random", share_fraction=1.0, strategy_settings=RandomSettings(share_tasks=2)),
    )
    batch = sharing(600, torch.Generator().manual_seed(0))
    source = replay.observation_at("task", batch.episode, 0)
    for j in range(env.num_tasks):
        sources = set(source[batch.obs["task"] == j].tolist())
        assert j not in sources and 1 <= len(sources) <= 2


def test_hipi_weights_are_the_posterior_with_its_partition_term():
    """Against an independent computation: each stored episode's return under every task summed step by step
    from the env's reward functions, then q(j | e) = exp(R_j(e)/T - log Z_j) / sum_j' exp(R_j'(e)/T - log Z_j'),
    log Z_j = log sum_e exp(R_j(e)/T), in float64 (the hindsight inverse-RL posterior over trajectories)."""
    env, replay = filled_replay(PointTasks, steps=400)
    temperature = 0.5
    sharing = TaskSharing(
        replay, env, env.num_tasks, SharingConfig(sharing="hipi", strategy_settings=HIPISettings(hipi_temperature=temperature))
    )
    source = replay.first_observations("task").long()
    weights = sharing.shared_weights(source, None)
    stored = replay.stored_episodes()
    flat = replay.episodes()  # the stored episodes, oldest first, read back flat
    returns = torch.zeros(len(flat.lengths), env.num_tasks, dtype=torch.float64)
    obs_at = step_at = 0
    for e, length in enumerate(flat.lengths.tolist()):
        for t in range(length):
            obs = {k: v[obs_at + t : obs_at + t + 1] for k, v in flat.obs.items()}
            next_obs = {k: v[obs_at + t + 1 : obs_at + t + 2] for k, v in flat.obs.items()}
            action = flat.action[step_at + t : step_at + t + 1]
            for j in range(env.num_tasks):
                returns[e, j] += float(env.task_reward(obs, action, next_obs, torch.tensor([j])))
        obs_at, step_at = obs_at + length + 1, step_at + length
    scaled = returns / temperature
    log_z = torch.log(torch.exp(scaled).sum(0))  # over episodes, per task
    unnormalised = torch.exp(scaled - log_z)
    posterior = unnormalised / unnormalised.sum(1, keepdim=True)
    other = source[stored, None] != torch.arange(env.num_tasks)
    assert torch.allclose(weights[:, stored].t().double(), posterior * other, atol=1e-5)
    assert bool((returns > 0).any())  # some episodes score under some task


def test_conservative_shares_less_than_all():
    env, replay = filled_replay(PointTasks)
    q = lambda obs, action: obs["observation"][:, 0] * (obs["task"].float() - 2.5)  # noqa: E731
    generator = torch.Generator().manual_seed(0)
    counted = {}
    for strategy in ("all", "conservative"):
        sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing=strategy), q_value=q)
        for _ in range(10):
            sharing(240, generator)
        counted[strategy] = sharing.metrics(env.task_set.names)["shared_fraction"]
    assert counted["all"] == pytest.approx(0.5)
    assert 0.05 < counted["conservative"] < counted["all"] - 0.1


def test_conservative_keeps_shared_rows_above_the_own_percentile():
    env, replay = filled_replay(PointTasks)
    q = lambda obs, action: obs["observation"][:, 1]  # noqa: E731  # Q = height
    sharing = TaskSharing(
        replay,
        env,
        env.num_tasks,
        SharingConfig(sharing="conservative", strategy_settings=ConservativeSettings(conservative_percentile=90)),
        q_value=q,
    )
    batch = sharing(600, torch.Generator().manual_seed(1))
    source = replay.observation_at("task", batch.episode, 0)
    shared = source != batch.obs["task"]
    own_heights = batch.obs["observation"][~shared, 1]
    assert bool(shared.any())
    assert batch.obs["observation"][shared, 1].min() > torch.quantile(own_heights, 0.5)


def test_sharing_composes_with_hindsight_goals():
    """Task relabelling first, then hindsight goals: every reward is r_task(achieved', goal')."""
    import gymnasium as gym

    space = gym.spaces.Dict(
        {
            "observation": gym.spaces.Box(-1, 1, (2,)),
            "achieved_goal": gym.spaces.Box(-1, 1, (2,)),
            "desired_goal": gym.spaces.Box(-1, 1, (2,)),
            "task": gym.spaces.Discrete(2),
        }
    )
    radius = torch.tensor([0.1, 0.5])  # task 0: reach the goal closely, task 1: roughly

    def reward(achieved, goal, info):
        return ((achieved - goal).norm(dim=-1) <= radius[info["task"].long()]).float() - 1

    class Tasks:
        def task_success(self, next_obs, task):
            return reward(next_obs["achieved_goal"], next_obs["desired_goal"], {"task": task}) == 0

        def task_reward(self, obs, action, next_obs, task):
            return self.task_success(next_obs, task).float() - 1

        def task_terminated(self, next_obs, task):
            return torch.zeros_like(task, dtype=torch.bool)

    replay = EpisodeReplay(space, gym.spaces.Box(-1, 1, (2,)), 10 * 200, num_envs=8, horizon=10)
    generator = torch.Generator().manual_seed(0)
    for e in range(40):
        walk = torch.rand(8, 11, 2, generator=generator) * 2 - 1
        tables = {
            "obs/observation": walk,
            "obs/achieved_goal": walk,
            "obs/desired_goal": torch.rand(8, 1, 2, generator=generator).expand(8, 11, 2) * 2 - 1,
            "obs/task": torch.full((8, 11), e % 2),
            "action": torch.zeros(8, 10, 2),
            "reward": torch.zeros(8, 10),
            "terminated": torch.zeros(8, 10, dtype=torch.bool),
            "truncated": torch.zeros(8, 10, dtype=torch.bool),
        }
        tables["truncated"][:, -1] = True
        flat = {k: v.reshape(-1, *v.shape[2:]) for k, v in tables.items()}
        replay.add_episodes(
            Episodes(
                obs={k[len("obs/") :]: v for k, v in flat.items() if k.startswith("obs/")},
                **{k: flat[k] for k in ("action", "reward", "terminated", "truncated")},
                lengths=torch.full((8,), 10),
            )
        )
    sharing = TaskSharing(replay, Tasks(), 2, SharingConfig(sharing="all"))
    her = HindsightRelabeler(reward, "future", 4, task_key="task")
    batch = her(sharing(512, generator), replay, generator)
    source = replay.observation_at("task", batch.episode, 0)
    stored_goal = replay.gather(batch.episode, batch.step).obs["desired_goal"]
    assert bool((source != batch.obs["task"]).any())  # task relabelled
    assert bool((batch.obs["desired_goal"] != stored_goal).any(-1).any())  # goals relabelled
    expected = reward(batch.next_obs["achieved_goal"], batch.obs["desired_goal"], {"task": batch.obs["task"]})
    assert torch.equal(batch.reward, expected)
    assert bool((batch.reward == 0).any())


@pytest.mark.parametrize("env_cls", ENVS)
def test_datasets_have_their_quality_and_size(env_cls):
    names = [t.name for t in (GRID_TASKS if env_cls is GridTasks else POINT_TASKS)]
    qualities = dict.fromkeys(names, "random")
    qualities[names[0]], qualities[names[1]] = "expert", "medium"
    env = env_cls(num_envs=10 * len(names), task_sampling="fixed", seed=0)
    episodes = collect_task_datasets(env, qualities, 400, seed=0)
    lengths = episodes.lengths
    task = episodes.obs["task"][torch.cumsum(lengths + 1, 0) - (lengths + 1)]  # each episode's first
    of_step = torch.arange(episodes.num_episodes).repeat_interleave(lengths)
    solved = torch.zeros(episodes.num_episodes).index_add_(0, of_step, episodes.reward) > 0
    for j in range(len(names)):
        assert int(lengths[task == j].sum()) == 400  # the same transitions per task
    # the fragments cut when collection stops: truncated before the horizon (one per env copy)
    cut = episodes.truncated[torch.cumsum(lengths, 0) - 1] & (lengths < env.horizon)
    assert int(cut.sum()) <= env.num_envs
    rate = [float(solved[(task == j) & ~cut].float().mean()) for j in range(3)]
    assert rate[0] > 0.9 and rate[0] >= rate[1] > rate[2]  # expert >= medium > random


def dataset_batch(obs_dim: int, action: torch.Tensor, terminated: bool) -> tuple[dict, Batch]:
    """A fixed batch of 256 random states, all with the given data ``action`` and reward 0."""
    torch.manual_seed(0)
    obs = {"observation": torch.randn(256, obs_dim)}
    batch = Batch(
        obs=obs,
        action=action,
        reward=torch.zeros(256),
        next_obs={"observation": torch.randn(256, obs_dim)},
        terminated=torch.full((256,), terminated),
        truncated=torch.zeros(256, dtype=torch.bool),
        episode=torch.zeros(256, dtype=torch.long),
        step=torch.zeros(256, dtype=torch.long),
    )
    return obs, batch


def test_cql_penalty_lowers_q_of_actions_the_data_never_took():
    """DQN: data with action 0 only; Q(s, a != 0) - Q(s, 0) ends lower with the penalty."""
    obs, batch = dataset_batch(4, torch.zeros(256, dtype=torch.long), terminated=False)
    gaps = {}
    for alpha in (0.0, 1.0):
        torch.manual_seed(0)
        agent = DQNAgent(("observation",), 4, 3, DQNConfig(cql_alpha=alpha, clip_target=False, normalize_inputs=False))
        for _ in range(200):
            metrics = agent.update(batch)
        with torch.no_grad():
            q = agent.q_values(obs)
        gaps[alpha] = float((q[:, 1:].mean(1) - q[:, 0]).mean())
    assert "cql_gap" in metrics
    assert gaps[1.0] < gaps[0.0] - 0.5


@pytest.mark.slow
def test_cql_penalty_lowers_sac_q_away_from_the_data():
    data_action = torch.full((256, 2), 0.5)
    obs, batch = dataset_batch(3, data_action, terminated=True)
    box = (torch.full((2,), -1.0), torch.ones(2))
    away = -data_action  # the opposite corner of the box
    gaps = {}
    for alpha in (0.0, 1.0):
        torch.manual_seed(0)
        agent = SACAgent(("observation",), 3, box, SACConfig(cql_alpha=alpha, hidden_sizes=(32, 32), lr=1e-3))
        for _ in range(150):
            agent.update(batch, torch.Generator().manual_seed(0))
        gaps[alpha] = float((agent.q_value(obs, away) - agent.q_value(obs, data_action)).mean())
    assert gaps[1.0] < gaps[0.0] - 0.5


def test_a_strategys_own_settings_are_flags_while_it_is_chosen_and_travel_with_the_run(tmp_path, capsys):
    """``--sharing random --share-tasks 2`` reaches the saved run and its sampler; the knob of a strategy not chosen is
    one line naming that strategy; a bad value names the knob. Mutation: `from_dict` leaving the strategy's section
    at its defaults fails."""
    from taskrl.cli import main
    from taskrl.config import load

    out = tmp_path / "run"
    argv = ["train", "grid-sharing-dqn", "--sharing", "random", "--share-tasks", "2", "--total-steps", "300"]
    assert main([*argv, "--learning-starts", "100", "--eval-interval", "1000000", "--out", str(out), "--no-progress"]) == 0
    saved = json.loads((out / "config.json").read_text())["data_sharing"]
    assert saved == {"sharing": "random", "share_fraction": 0.5, "random": {"share_tasks": 2}}
    assert load(out / "config.json").data_sharing.strategy_settings.share_tasks == 2
    capsys.readouterr()
    assert main(["train", "grid-sharing-dqn", "--share-tasks", "2", "--total-steps", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sharing random" in err[0], err
    base = with_overrides(TrainConfig(), {"env": "gridtasks", "her": "none", "sampling": "task_balanced"})
    with pytest.raises(ConfigError) as error:
        with_overrides(base, {"sharing": "all", "hipi_temperature": 2.0})
    assert error.value.field == "hipi_temperature" and "--sharing hipi" in error.value.message
    with pytest.raises(ConfigError) as error:
        validate(with_overrides(base, {"sharing": "hipi", "hipi_temperature": 0.0}))
    assert error.value.field == "hipi_temperature"


def test_bad_sharing_settings_are_one_line_errors():
    base = with_overrides(TrainConfig(), {"env": "gridtasks", "her": "none", "sampling": "task_balanced"})
    cases = {
        "sharing": {"sharing": "everything"},
        "share_fraction": {"sharing": "all", "share_fraction": 1.5},
        "low_data_tasks": {"low_data_tasks": "nowhere"},
        "dataset_quality": {"dataset_quality": "top-left=superb"},
        "offline": {"offline": True},
    }
    for field, overrides in cases.items():
        with pytest.raises(ConfigError) as error:
            validate(with_overrides(base, overrides))
        assert error.value.field == field
    with pytest.raises(ConfigError) as error:
        validate(with_overrides(base, {"sharing": "all", "sampling": "uniform"}))
    assert error.value.field == "sampling"
    with pytest.raises(ConfigError) as error:  # an env whose tasks are not reward functions
        small_run("pointreach-mt-sac-onehot", None, sharing="all", total_steps=100)
    assert error.value.field == "sharing"


@pytest.mark.slow
def test_sharing_solves_a_low_data_task_that_none_does_not(tmp_path):
    """The grid preset at a small budget: sharing all tasks' data solves the task with a tenth of the
    episodes; its own data alone does not, at the same budget and seed."""
    success = {}
    for strategy in ("none", "all"):
        run = small_run("grid-sharing-dqn", tmp_path / strategy, sharing=strategy, total_steps=8_000, seed=0)
        rows = list(csv.DictReader(open(run.run_dir / "metrics.csv")))
        success[strategy] = float(rows[-1]["success/top-left-avoid"])
        shared = float(rows[-1]["shared/top-left-avoid"])
        assert shared == (0.0 if strategy == "none" else pytest.approx(0.5, abs=0.03))  # 22 of 42-43 rows
    assert success["all"] >= 0.8
    assert success["none"] <= 0.4


@pytest.mark.slow
def test_offline_run_learns_from_datasets_without_stepping_an_env(tmp_path):
    run = small_run(
        "point-sharing-offline",
        tmp_path / "offline",
        total_steps=400,
        eval_interval=200,
        dataset_steps=400,
        cql_samples=2,
        eval_episodes=4,
    )
    rows = list(csv.DictReader(open(run.run_dir / "metrics.csv")))
    assert [int(r["updates"]) for r in rows] == [1, 200, 400]  # the untrained policy's evaluation first
    assert all(int(r["env_steps"]) == 0 for r in rows)
    assert run.metrics["updates"] == 400
    assert (run.run_dir / "checkpoints").exists()
    assert math.isfinite(float(rows[-1]["cql_gap"]))
    assert 0.0 < float(rows[-1]["shared_fraction"]) <= 0.5  # conservative shares some, not all
    # its checkpoints leave the (unchanging) datasets out, and a resumed run reads them again
    saved = sorted(p.name for p in latest_checkpoint(run.run_dir / "checkpoints").iterdir())
    assert saved == ["agent.json", "agent.safetensors", "loop.json", "loop.safetensors"]
    more = taskrl.train(resume=run.run_dir, total_steps=600, tensorboard=False)
    assert more.metrics["updates"] == 600
    assert more.metrics["replay_transitions"] == run.metrics["replay_transitions"] > 0


@pytest.mark.slow
def test_a_grid_run_under_capacity_stores_every_step_it_collected(tmp_path):
    """Episodes end early on the grid (success, failure): the replay keeps all of them, counted in transitions."""
    from taskrl.checkpoint import load_checkpoint
    from taskrl.replay.storage import saved_episodes

    run = small_run(
        "grid-sharing-dqn",
        tmp_path / "grid",
        total_steps=4_000,
        eval_interval=2_000,
        buffer_size=1_000_000,
        save_replay=True,
        progress=False,
    )
    last = list(csv.DictReader(open(run.run_dir / "metrics.csv")))[-1]
    episodes, _ = saved_episodes(load_checkpoint(run.run_dir / "checkpoints", ("replay",), "cpu")["replay"])
    assert episodes.num_transitions == run.metrics["env_steps"]  # every step, the running episodes cut at the end
    # the last row was written before those were cut: it counts the completed episodes' steps exactly
    ends = torch.cumsum(episodes.lengths, 0) - 1
    cut = episodes.truncated[ends] & (episodes.lengths < 30)  # cut at the end, not at the grid's time limit
    assert int(last["replay_transitions"]) == run.metrics["env_steps"] - int(episodes.lengths[cut].sum())
    assert int(last["replay_evicted"]) == 0 and int(last["replay_episodes"]) == episodes.num_episodes - int(cut.sum())
    # episodes end early: more of them than rows of the grid's 30-step horizon the run's steps would fill
    assert episodes.num_episodes > (4_000 + 2 * run.config.num_envs * 30) / 30


def test_a_recent_window_composes_with_a_sharing_strategy_in_the_sampler_pipeline(tmp_path):
    """Recent-mix over ``all`` sharing: the window's rows train the task they were collected for, with their
    stored reward; the rest are the strategy's, relabelled with the task they train."""
    from taskrl.replay.pipeline import SamplerPipeline
    from taskrl.replay.sampling import RecentMixSampler

    env, replay = filled_replay(GridTasks)
    sharing = TaskSharing(replay, env, env.num_tasks, SharingConfig(sharing="all", share_fraction=1.0))
    pipeline = SamplerPipeline(replay, RecentMixSampler(replay, 0.25, 20, sharing), [sharing.to_task])
    batch = pipeline(240, torch.Generator().manual_seed(0))
    source = replay.observation_at("task", batch.episode, 0)
    window, rest = slice(0, 60), slice(60, 240)
    newest = set(replay.newest_episodes(20).tolist())
    assert set(batch.episode[window].tolist()) <= newest
    assert torch.equal(batch.obs["task"][window], source[window])  # own task
    assert torch.equal(batch.reward[window], replay.gather(batch.episode[window], batch.step[window]).reward)
    assert (batch.obs["task"][rest] != source[rest]).all()  # share_fraction 1: all shared
    expected = env.task_reward(batch.obs, batch.action, batch.next_obs, batch.obs["task"])
    assert torch.equal(batch.reward, expected.to(batch.reward.dtype))
    assert (batch.reward[rest] != replay.gather(batch.episode[rest], batch.step[rest]).reward).any()
    # and a run with both trains
    run = small_run("grid-sharing-dqn", tmp_path / "mixed", recent_fraction=0.3, total_steps=600, eval_interval=300)
    assert run.config.data_sharing.sharing == "all" and run.metrics["updates"] > 0


def test_stored_datasets_are_drawn_apart_from_the_training_envs_stream():
    """The family's datasets come from their own seed (the run's seed + DATASET_SEED_OFFSET), not the training env's.
    Mutation: passing the run's seed to ``collect_task_datasets`` (the old line) makes both datasets equal."""
    import dataclasses

    from taskrl.envs.registry import env_family
    from taskrl.presets import preset_config
    from taskrl.run import build
    from taskrl.wiring.parts import env_request
    from taskrl.wiring.stored_data import _dataset_copies, preload_datasets

    config = with_overrides(preset_config("point-sharing-offline"), {"dataset_steps": 40, "seed": 3})
    parts = build(config)
    try:
        added = []
        parts.replay.add_episodes = added.append  # what would be stored
        preload_datasets(parts)
        stored = added[0].obs["observation"]
        settings = config.env_settings
        request = env_request(config, parts.device, parts.source, evaluation=True, seed=config.seed)
        maker = env_family(config.env).make(settings, dataclasses.replace(request, eval_episodes=_dataset_copies(40)))
        qualities = dict(q.split("=") for q in settings.dataset_quality.split(","))
        same_seed = collect_task_datasets(maker, qualities, 40, config.seed)
        maker.close()
    finally:
        parts.close()
    assert stored.shape == same_seed.obs["observation"].shape
    assert not torch.equal(stored, same_seed.obs["observation"])
