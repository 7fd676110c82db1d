"""Meta-World runs end to end, at smoke-test size: wiring, per-task evaluation, checkpoints."""

import json

import pytest
import torch

import taskrl
from helpers import small_run
from taskrl.config import ConfigError

pytest.importorskip("metaworld")


@pytest.mark.slow
def test_mt10_care_run_writes_per_task_results_and_reloads(tmp_path):
    out = tmp_path / "mt10"
    run = small_run(
        "mt10-sac-care",
        out,
        total_steps=600,
        learning_starts=300,
        max_episode_steps=30,
        hidden_sizes=(32, 32),
        batch_size=40,
        eval_interval=10**6,
        eval_episodes=2,
        buffer_size=2_000,
    )
    per_task = json.loads((out / "per_task_success.json").read_text())
    assert per_task["distinct_goals"] is True and per_task["success"] == "reached at any step"
    assert list(per_task["tasks"]) == [
        "reach",
        "push",
        "pick-place",
        "door-open",
        "drawer-open",
        "drawer-close",
        "button-press-topdown",
        "peg-insert-side",
        "window-open",
        "window-close",
    ]
    assert all(t["episodes"] == 2 and t["mean_length"] == 30 for t in per_task["tasks"].values())
    assert run.metrics["updates"] > 0 and "success/peg-insert-side" in run.metrics
    agent = run.agent
    assert agent.conditioning.config.architecture == "care" and agent.task_encoder.context_dim == 50
    assert agent.log_alpha.shape == (10,)  # one temperature per task
    loaded = taskrl.load(out)
    obs = {"observation": torch.randn(10, 39), "task": torch.arange(10)}
    torch.testing.assert_close(loaded.act(obs), agent.act(obs))


@pytest.mark.slow
def test_mt1_run_has_no_task_context(tmp_path):
    run = small_run(
        "mt1-reach-sac",
        tmp_path / "mt1",
        total_steps=400,
        learning_starts=200,
        num_envs=2,
        max_episode_steps=20,
        hidden_sizes=(16,),
        batch_size=16,
        eval_interval=10**6,
        eval_episodes=1,
        buffer_size=1_000,
    )
    assert run.agent.conditioning is None and "success/reach" in run.metrics


def test_metaworld_settings_are_checked_before_anything_is_built(tmp_path):
    with pytest.raises(ConfigError) as err:
        taskrl.train("mt10-sac-onehot", out=tmp_path / "bad", num_envs=15)
    assert err.value.field == "num_envs" and "multiple of the 10 tasks" in str(err.value)


@pytest.mark.slow
def test_a_task_file_of_metaworld_names_runs_with_its_own_descriptions(tmp_path):
    """Tasks without an env are Meta-World tasks: a custom set keeps the user's sentences and Meta-World's
    any-step success."""
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text(
        "tasks:\n  - {name: reach, description: Touch the goal with the gripper.}\n"
        "  - {name: drawer-close, description: Shut the drawer.}\n"
    )
    run = taskrl.train(
        "mt10-sac-onehot",
        env=None,
        task_file=str(tasks),
        out=tmp_path / "run",
        num_envs=2,
        total_steps=200,
        learning_starts=100,
        max_episode_steps=20,
        eval_episodes=2,
        batch_size=32,
        hidden_sizes=(16,),
        tensorboard=False,
    )
    per_task = json.loads((run.run_dir / "per_task_success.json").read_text())
    assert run.config.env == "tasks" and per_task["success"] == "reached at any step" and per_task["distinct_goals"]
    assert {k: v["description"] for k, v in per_task["tasks"].items()} == {
        "reach": "Touch the goal with the gripper.",
        "drawer-close": "Shut the drawer.",
    }
    assert run.agent.conditioning.num_tasks == 2
