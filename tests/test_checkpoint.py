import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import taskrl
from taskrl.agents.dqn import DQNAgent, DQNConfig
from taskrl.checkpoint import flatten_state, load_checkpoint, save_checkpoint, unflatten_state
from taskrl.logger import read_metrics

# eager (compile off): these runs time their steps, and --compile auto would compile the long-budget ones
TINY = dict(n_bits=5, num_envs=4, eval_episodes=20, tensorboard=False, learning_starts=100, batch_size=32, compile="off")


def test_state_round_trip_keeps_optimizer_state_and_int_keys(tmp_path):
    agent = DQNAgent(("observation",), 3, 2, DQNConfig(hidden_sizes=(8,)))
    agent.inputs.normalize.update(torch.randn(5, 3))
    agent.q(agent.inputs({"observation": torch.ones(1, 3)})).sum().backward()
    agent.optimizer.step()
    state = agent.state_dict()
    save_checkpoint(tmp_path, {"agent": state}, step=7)
    loaded = load_checkpoint(tmp_path, ("agent",))["agent"]
    assert list(loaded["optimizer"]["state"]) == list(state["optimizer"]["state"])  # int keys survive
    for k, v in state["q"].items():
        assert torch.equal(loaded["q"][k], v)
    assert torch.equal(loaded["normalize"]["mean"], agent.inputs.normalize.mean)  # input statistics travel too
    other = DQNAgent(("observation",), 3, 2, DQNConfig(hidden_sizes=(8,)))
    other.load_state_dict(loaded)
    assert other.updates == agent.updates
    tensors, skeleton = flatten_state({"a": [1, 2.5, "x", None, torch.arange(3)]})
    assert torch.equal(unflatten_state(tensors, skeleton)["a"][4], torch.arange(3))


def test_checkpoint_files_are_safetensors_and_json_only(tmp_path):
    save_checkpoint(tmp_path, {"agent": {"w": torch.zeros(2)}, "loop": {"env_steps": 3}}, step=3)
    folder = tmp_path / (tmp_path / "latest").read_text().strip()
    assert sorted(p.name for p in folder.iterdir()) == ["agent.json", "agent.safetensors", "loop.json", "loop.safetensors"]
    for p in folder.glob("*.json"):
        json.loads(p.read_text())


def test_a_half_written_checkpoint_is_never_loaded(tmp_path):
    save_checkpoint(tmp_path, {"loop": {"env_steps": 1}}, step=1)
    # A run killed while writing leaves only a .partial folder; 'latest' still names the old one.
    (tmp_path / ".step_000000000002.partial").mkdir()
    (tmp_path / ".step_000000000002.partial" / "loop.json").write_text("{trunc")
    assert load_checkpoint(tmp_path, ("loop",))["loop"]["env_steps"] == 1


def test_only_the_newest_checkpoints_are_kept(tmp_path):
    for step in range(5):
        save_checkpoint(tmp_path, {"loop": {"env_steps": step}}, step=step, keep=2)
    assert sorted(p.name for p in tmp_path.glob("step_*")) == ["step_000000000003", "step_000000000004"]


@pytest.mark.slow
def test_resume_continues_counters_weights_and_metrics(tmp_path):
    out = tmp_path / "run"
    first = taskrl.train("bitflip-her", out=out, total_steps=2_000, eval_interval=500, checkpoint_interval=1_000, **TINY)
    saved_q = {k: v.clone() for k, v in first.agent.q.state_dict().items()}
    resumed_agent = taskrl.load(out)
    assert all(torch.equal(resumed_agent.q.state_dict()[k], v) for k, v in saved_q.items())
    second = taskrl.train(resume=out, total_steps=4_000, tensorboard=False)
    assert second.metrics["env_steps"] == 4_000
    assert second.metrics["updates"] > first.metrics["updates"]
    assert second.metrics["wall_seconds"] > first.metrics["wall_seconds"]
    steps = [r["env_steps"] for r in read_metrics(out / "metrics.csv")]
    assert steps == sorted(set(steps)) and steps[-1] == 4_000
    assert json.loads((out / "config.json").read_text())["total_steps"] == 4_000


@pytest.mark.slow
def test_a_killed_run_resumes_from_its_last_checkpoint(tmp_path):
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "taskrl.cli",
        "train",
        "bitflip-her",
        "--out",
        str(out),
        "--no-progress",
        "--no-tensorboard",
        "--n-bits",
        "6",
        "--num-envs",
        "4",
        "--total-steps",
        "10000000",
        "--checkpoint-interval",
        "400",
        "--eval-interval",
        "400",
        "--eval-episodes",
        "10",
        "--learning-starts",
        "100",
        "--compile",
        "off",  # eager, as the steps it times before the kill assume (auto would compile a 10M-step run)
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while not (out / "checkpoints" / "latest").exists():
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.time() < deadline
        time.sleep(0.2)
    time.sleep(1.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    saved_steps = load_checkpoint(out / "checkpoints", ("loop",))["loop"]["env_steps"]
    assert saved_steps >= 400
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "taskrl.cli",
            "train",
            "--resume",
            str(out),
            "--no-progress",
            "--no-tensorboard",
            "--total-steps",
            str(saved_steps + 800),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    final = json.loads(result.stdout.strip().splitlines()[-1])
    assert final["env_steps"] == saved_steps + 800
    steps = [r["env_steps"] for r in read_metrics(out / "metrics.csv")]
    assert steps == sorted(set(steps))  # rows written after the last checkpoint were dropped
    assert Path(out / "learning_curve.png").stat().st_size > 1000


@pytest.mark.slow
def test_metrics_csv_gains_the_agents_columns_after_the_first_updates(tmp_path):
    run = taskrl.train("bitflip-her", out=tmp_path / "cols", total_steps=600, eval_interval=200, **TINY)
    rows = read_metrics(tmp_path / "cols" / "metrics.csv")
    assert {"loss", "q_mean", "success_rate", "wall_seconds"} <= set(rows[0])
    assert rows[0]["loss"] is None and rows[-1]["loss"] is not None  # no updates before the first row
    assert run.metrics["updates"] > 0


@pytest.mark.slow
def test_a_time_limit_stops_cleanly_and_resume_finishes_the_run(tmp_path):
    out = tmp_path / "limited"
    first = taskrl.train(
        "bitflip-her", out=out, total_steps=10_000_000, eval_interval=400, checkpoint_interval=10**9, max_hours=2 / 3600, **TINY
    )
    assert first.stopped_by == "time limit"
    stopped_at = first.metrics["env_steps"]
    assert 0 < stopped_at < 10_000_000
    # the stop wrote a checkpoint at the step it stopped on, and a metrics row for it
    assert load_checkpoint(out / "checkpoints", ("loop",))["loop"]["env_steps"] == stopped_at
    assert read_metrics(out / "metrics.csv")[-1]["env_steps"] == stopped_at
    second = taskrl.train(resume=out, total_steps=stopped_at + 400, max_hours=0, tensorboard=False)
    assert second.stopped_by is None and second.metrics["env_steps"] == stopped_at + 400
    steps = [r["env_steps"] for r in read_metrics(out / "metrics.csv")]
    assert (stopped_at // 400 + 1) * 400 in steps  # the stop's extra evaluation did not shift the schedule


@pytest.mark.slow
def test_sigterm_stops_a_cli_run_with_a_checkpoint_at_the_current_step(tmp_path):
    out = tmp_path / "terminated"
    cmd = [
        sys.executable,
        "-m",
        "taskrl.cli",
        "train",
        "bitflip-her",
        "--out",
        str(out),
        "--no-progress",
        "--no-tensorboard",
        "--n-bits",
        "6",
        "--num-envs",
        "4",
        "--total-steps",
        "10000000",
        "--checkpoint-interval",
        "1000000000",
        "--eval-interval",
        "400",
        "--eval-episodes",
        "10",
        "--learning-starts",
        "100",
        "--compile",
        "off",  # eager: the steps it waits for assume it (auto would compile a 10M-step run)
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not ((out / "metrics.csv").exists() and len(read_metrics(out / "metrics.csv")) >= 3):
        assert proc.poll() is None, proc.stderr.read()
        assert time.time() < deadline
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    assert "stopped early (SIGTERM)" in stderr and f"--resume {out}" in stderr
    final = json.loads(stdout.strip().splitlines()[-1])
    assert load_checkpoint(out / "checkpoints", ("loop",))["loop"]["env_steps"] == final["env_steps"] > 400
