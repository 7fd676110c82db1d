"""A user's own environments and task sets, as a user would bring them.

The envs are defined here and registered with gymnasium when this module is imported (so
``--env-module test_custom_envs`` registers them in a fresh process, with ``tests/`` on the path).
Each learning test asserts a success rate a random policy does not reach (about 0.1 on the slider).
"""

import csv
import json
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import taskrl
from helpers import cli, cli_train, successes
from taskrl.errors import ConfigError
from taskrl.tasks import TaskSet, TaskSpec

TESTS = Path(__file__).parent


class Slider(gym.Env):
    """A block on a rail [-1, 1] to move to a random goal (within 0.1); sparse reward, a goal env."""

    metadata = {"render_modes": []}

    def __init__(self, speed: float = 0.2):
        self.speed = speed
        box = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = gym.spaces.Dict({"observation": box, "achieved_goal": box, "desired_goal": box})
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def _obs(self):
        x = np.array([self.x], dtype=np.float32)
        return {"observation": x, "achieved_goal": x.copy(), "desired_goal": np.array([self.goal], dtype=np.float32)}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.goal = (float(v) for v in self.np_random.uniform(-1, 1, size=2))
        return self._obs(), {}

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        return -(np.abs(np.asarray(achieved_goal) - np.asarray(desired_goal))[..., 0] > 0.1).astype(np.float32)

    def step(self, action):
        self.x = float(np.clip(self.x + self.speed * float(np.asarray(action).reshape(-1)[0]), -1, 1))
        obs = self._obs()
        reward = float(self.compute_reward(obs["achieved_goal"], obs["desired_goal"]))
        return obs, reward, False, False, {"is_success": reward == 0.0}


class SliderThatEnds(Slider):
    """The slider ending its own episodes: at the goal (``terminated``) or after its own 25 steps
    (``truncated``), with no ``max_episode_steps`` registered: the replay discovers the lengths."""

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return super().reset(seed=seed, options=options)

    def step(self, action):
        obs, reward, _, _, info = super().step(action)
        self.t += 1
        return obs, reward, reward == 0.0, self.t >= 25, info


class SlideTo(gym.Env):
    """The block to a fixed ``target``; a plain Box observation (the position) and a dense reward."""

    metadata = {"render_modes": []}

    def __init__(self, target: float = 0.0):
        self.target = target
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return np.array([self.x], dtype=np.float32), {}

    def step(self, action):
        self.x = float(np.clip(self.x + 0.2 * float(np.asarray(action).reshape(-1)[0]), -1, 1))
        distance = abs(self.x - self.target)
        return np.array([self.x], dtype=np.float32), -distance, False, False, {"is_success": distance <= 0.1}


class Corridor(gym.Env):
    """Cells 0..8, start in the middle; the goal is one end, drawn each episode and shown as -1 / +1.
    Actions left / right (Discrete), -1 per step; a plain Box observation ``[position, goal side]``.
    A policy that ignores the goal side reaches at most half of the goals."""

    metadata = {"render_modes": []}
    length = 8

    def __init__(self):
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(2)

    def _obs(self):
        return np.array([2 * self.cell / self.length - 1, self.side], dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.cell, self.side = self.length // 2, float(self.np_random.choice([-1.0, 1.0]))
        return self._obs(), {}

    def step(self, action):
        self.cell = int(np.clip(self.cell + (1 if int(action) == 1 else -1), 0, self.length))
        done = self.cell == (self.length if self.side > 0 else 0)
        return self._obs(), -1.0, done, False, {"is_success": done}


for env_id, entry, steps in (
    ("testenvs/Slider-v0", Slider, 20),
    ("testenvs/SlideTo-v0", SlideTo, 20),
    ("testenvs/Corridor-v0", Corridor, 30),
):
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=entry, max_episode_steps=steps)
if "testenvs/SliderThatEnds-v0" not in gym.registry:  # no time limit declared
    gym.register("testenvs/SliderThatEnds-v0", entry_point=SliderThatEnds)

SMALL = dict(total_steps=3000, eval_interval=1500, eval_episodes=50, learning_starts=500, tensorboard=False)


def cli_train_slider(env_id: str, out: Path, cwd: Path) -> subprocess.CompletedProcess:
    """``taskrl train pointreach-sac-her`` on a registered slider, with :data:`SMALL`'s budget."""
    budget = ["--total-steps", "3000", "--eval-interval", "1500", "--eval-episodes", "50", "--learning-starts", "500"]
    common = ["--env-module", "test_custom_envs", "--no-tensorboard"]
    return cli_train("pointreach-sac-her", "--env-id", env_id, "--out", str(out), *budget, *common, cwd=cwd)


@pytest.mark.slow
def test_cli_trains_resumes_evaluates_and_loads_a_registered_goal_env(tmp_path):
    out = tmp_path / "slider"
    common = ["--env-module", "test_custom_envs", "--no-progress", "--no-tensorboard"]
    first = cli_train_slider("testenvs/Slider-v0", out, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    saved = json.loads((out / "config.json").read_text())
    assert (saved["env"], saved["gym"]["env_id"], saved["algo"], saved["env_module"]) == (
        "gym",
        "testenvs/Slider-v0",
        "sac",
        "test_custom_envs",
    )
    more = cli("train", "--resume", str(out), "--total-steps", "6000", *common, cwd=tmp_path)
    assert more.returncode == 0, more.stderr
    curve = successes(out)
    assert curve[0] < 0.3 and max(curve[-2:]) >= 0.9, curve  # random: ~0.1; trained: >= 0.9
    assert int(json.loads(more.stdout)["env_steps"]) >= 6000
    assert (out / "learning_curve.png").exists() and len(list((out / "checkpoints").glob("step_*"))) >= 1

    # A fresh process does not import a module a run directory names: it says which flag to pass.
    refused = cli("eval", str(out), "--episodes", "20", cwd=tmp_path)
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert "--env-module" in refused.stderr
    evaluated = cli("eval", str(out), "--episodes", "50", "--env-module", "test_custom_envs", "--json", cwd=tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr
    assert json.loads(evaluated.stdout)["success_rate"] >= 0.8

    agent = taskrl.load(out)  # registered here: this module is imported
    env = gym.make("testenvs/Slider-v0")
    obs, _ = env.reset(seed=5)
    for _ in range(20):
        obs, _, _, _, info = env.step(agent.act(obs))
    assert env.action_space.contains(agent.act(obs)) and info["is_success"]


@pytest.mark.slow
def test_api_trains_on_a_factory_and_needs_it_again_to_resume_and_load(tmp_path):
    run = taskrl.train("pointreach-sac-her", env=Slider, max_episode_steps=20, out=tmp_path / "factory", **SMALL)
    assert run.config.env == "gym" and run.config.env_settings.env_id == "python:test_custom_envs.Slider"
    assert successes(run.run_dir)[-1] >= 0.9
    with pytest.raises(ConfigError, match="pass it again"):
        taskrl.train(resume=run.run_dir, total_steps=4500)
    resumed = taskrl.train(resume=run.run_dir, env=Slider, total_steps=4500, tensorboard=False)
    assert resumed.metrics["env_steps"] >= 4500 and resumed.metrics["success_rate"] >= 0.9
    agent = taskrl.load(run.run_dir, env=Slider)
    vec = gym.make_vec("testenvs/Slider-v0", num_envs=4)
    obs, _ = vec.reset(seed=0)
    actions = agent.act(obs)  # a batch of numpy observations from gymnasium's vector env
    assert isinstance(actions, np.ndarray) and actions.shape == (4, 1)
    vec.step(actions)
    vec.close()


@pytest.mark.slow
def test_a_goal_env_without_max_episode_steps_trains_from_the_command_line_and_from_python(tmp_path):
    assert gym.spec("testenvs/SliderThatEnds-v0").max_episode_steps is None
    out = tmp_path / "ends-cli"
    done = cli_train_slider("testenvs/SliderThatEnds-v0", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert successes(out)[-1] >= 0.9

    run = taskrl.train("pointreach-sac-her", env=SliderThatEnds, out=tmp_path / "ends-api", **SMALL)
    rows = list(csv.DictReader(open(run.run_dir / "metrics.csv")))
    assert successes(run.run_dir)[-1] >= 0.9
    # episodes of their own lengths, every completed step kept (the run never filled its replay)
    assert 1 < float(rows[-1]["eval_length"]) < 25
    assert int(rows[-1]["replay_evicted"]) == 0 and 2000 < int(rows[-1]["replay_transitions"]) <= 3000


@pytest.mark.slow
def test_a_plain_discrete_env_trains_with_dqn_and_bad_input_is_one_line(tmp_path):
    run = taskrl.train(
        "bitflip-dqn",
        env="testenvs/Corridor-v0",
        out=tmp_path / "corridor",
        num_envs=8,
        total_steps=4000,
        eval_interval=1000,
        eval_episodes=50,
        learning_starts=200,
        updates_per_step=0.25,
        gamma=0.9,
        tensorboard=False,
    )
    assert run.config.env == "gym" and successes(run.run_dir)[-1] >= 0.95  # ignoring the goal side: at most 0.5
    with pytest.raises(ConfigError, match="goal env") as err:  # hindsight relabelling on a plain env
        taskrl.train("bitflip-her", env="testenvs/Corridor-v0", out=tmp_path / "her", total_steps=100)
    assert err.value.field == "her" and not (tmp_path / "her").exists()  # nothing left behind
    with pytest.raises(ConfigError) as err:
        taskrl.train("bitflip-her", env="testenvs/NoSuchEnv-v0", out=tmp_path / "nope", total_steps=100)
    assert err.value.field == "env_id" and "--env-module" in err.value.message
    with pytest.raises(ConfigError) as err:  # Box actions for a discrete-action algorithm
        taskrl.train("bitflip-dqn", env="testenvs/SlideTo-v0", out=tmp_path / "box", total_steps=100)
    assert err.value.field == "algo" and "allowed: qtopt, sac, td3, ppo" in err.value.message


def slide_tasks() -> TaskSet:
    return TaskSet(
        [
            TaskSpec("left", "Slide the block to the left end of the rail.", 0, "testenvs/SlideTo-v0", {"target": -0.7}),
            TaskSpec("middle", "Slide the block to the middle of the rail.", 1, "testenvs/SlideTo-v0", {"target": 0.0}),
            TaskSpec("right", "Slide the block to the right end of the rail.", 2, "testenvs/SlideTo-v0", {"target": 0.7}),
        ]
    )


@pytest.mark.slow
def test_a_custom_three_task_set_trains_with_language_conditioning(tmp_path):
    """From the same position the three tasks need opposite actions: without the task at most ~1/3 succeed."""
    run = taskrl.train(
        "pointreach-mt-sac-onehot",
        env=slide_tasks(),
        task_encoder="language",
        projection_dim=16,
        out=tmp_path / "tasks",
        num_envs=15,
        total_steps=6000,
        eval_interval=1500,
        eval_episodes=10,
        learning_starts=500,
        tensorboard=False,
    )
    assert run.config.env == "tasks" and run.agent.conditioning.config.task_encoder == "language"
    per_task = json.loads((run.run_dir / "per_task_success.json").read_text())
    assert per_task["mean_success_rate"] >= 0.9 and min(t["success_rate"] for t in per_task["tasks"].values()) >= 0.7
    assert per_task["tasks"]["left"]["description"] == "Slide the block to the left end of the rail."
    saved = json.loads((run.run_dir / "tasks.json").read_text())["tasks"]
    assert [t["env_kwargs"]["target"] for t in saved] == [-0.7, 0.0, 0.7]
    again = taskrl.load(run.run_dir)  # string ids: the run directory alone rebuilds the task set
    obs = {"observation": np.array([0.0], dtype=np.float32), "task": np.int64(0)}
    assert again.act(obs)[0] < 0  # "left" from the middle: move left
    assert again.act({**obs, "task": np.int64(2)})[0] > 0


@pytest.mark.slow
def test_a_task_file_is_read_by_the_command_line(tmp_path, capsys):
    from taskrl.cli import main

    file = tmp_path / "tasks.yaml"
    file.write_text(
        "tasks:\n"
        + "".join(
            f"  - {{name: {t.name}, description: {t.description}, env: testenvs/SlideTo-v0, env_kwargs: {{target: {t.env_kwargs['target']}}}}}\n"
            for t in slide_tasks()
        )
    )
    code = main(
        [
            "train",
            "pointreach-mt-sac-onehot",
            "--task-file",
            str(file),
            "--num-envs",
            "6",
            "--total-steps",
            "300",
            "--learning-starts",
            "100",
            "--eval-episodes",
            "2",
            "--out",
            str(tmp_path / "run"),
            "--no-progress",
            "--no-tensorboard",
        ]
    )
    first = capsys.readouterr().err
    assert code == 0, first
    assert "note: --env tasks: pointreach-mt's reward=dense does not apply" in first  # what the preset loses, said once
    assert set(json.loads((tmp_path / "run" / "per_task_success.json").read_text())["tasks"]) == {"left", "middle", "right"}
    code = main(
        ["train", "pointreach-mt-sac-onehot", "--task-file", str(file), "--num-envs", "4", "--out", str(tmp_path / "bad")]
    )
    err = capsys.readouterr().err
    assert code == 2 and "--num-envs must be a multiple of the 3 tasks" in err and len(err.strip().splitlines()) == 1
