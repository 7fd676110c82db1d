import json
import subprocess
import sys

import pytest

from taskrl.cli import main


def run_cli(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_presets_lists_each_with_a_description(capsys):
    code, out, _ = run_cli(capsys, "presets")
    assert code == 0
    lines = dict(line.split(None, 1) for line in out.strip().splitlines())
    assert {"bitflip-her", "bitflip-dqn"} <= set(lines)
    assert all(len(desc) > 20 for desc in lines.values())


@pytest.mark.parametrize(
    "args, expected",
    [
        (["train", "no-such-preset"], "bitflip-her"),
        (["train", "bitflip-her", "--n-bits", "0"], "--n-bits must be >= 1"),
        (["train", "bitflip-her", "--her", "sometimes"], "'future', 'final', 'episode', 'random', 'none'"),
        (["train", "bitflip-her", "--n-bit", "3"], "did you mean --n-bits?"),
        (["train", "bitflip-her", "--loss", "l1"], "'huber', 'mse'"),
        (["train", "bitflip-her", "--gamma", "1.0"], "--gamma must be in [0, 1)"),
        (["train", "bitflip-her", "--device", "tpu"], "allowed: cpu, cuda, cuda:N, auto"),
        (["train"], "allowed: bitflip-her"),
        (["fly"], "allowed: train, eval, presets, solve"),
        (["eval", "/nonexistent/run"], "not a run directory"),
        (["train", "mt10-sac-care", "--architecture", "transformer"], "'concat', 'film', 'care'"),
        (["train", "mt10-sac-care", "--num-envs", "12"], "--num-envs must be a multiple of the 10 tasks"),
        (["train", "mt10-ppo-onehot", "--estimator", "a2c"], "'ppo', 'reinforce'"),
        (["train", "pointreach-mt-sac-onehot", "--algo", "dqn"], "allowed: sac, ppo"),
    ],
)
def test_bad_input_gets_one_line_naming_the_allowed_values_and_exit_2(capsys, args, expected):
    code, out, err = run_cli(capsys, *args)
    assert code == 2
    assert len(err.strip().splitlines()) == 1
    assert expected in err


def test_refuses_to_overwrite_an_existing_run(capsys, tmp_path):
    (tmp_path / "checkpoints").mkdir()
    code, _, err = run_cli(capsys, "train", "bitflip-her", "--out", str(tmp_path))
    assert code == 2 and "--resume" in err


def test_train_then_eval_from_the_command_line(tmp_path):
    out = tmp_path / "cli-run"
    train = subprocess.run(
        [sys.executable, "-m", "taskrl.cli", "train", "bitflip-her", "--out", str(out), "--n-bits", "4",
         "--num-envs", "4", "--total-steps", "1500", "--eval-interval", "500", "--eval-episodes", "20",
         "--learning-starts", "100", "--hidden-sizes", "32", "32", "--no-progress"],
        capture_output=True, text=True, timeout=300)
    assert train.returncode == 0, train.stderr
    for name in ("config.json", "metrics.csv", "learning_curve.png"):
        assert (out / name).exists()
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    assert json.loads((out / "config.json").read_text())["dqn"]["hidden_sizes"] == [32, 32]
    header = (out / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"env_steps", "wall_seconds", "success_rate"} <= set(header)
    ev = subprocess.run([sys.executable, "-m", "taskrl.cli", "eval", str(out), "--episodes", "50"],
                        capture_output=True, text=True, timeout=300)
    assert ev.returncode == 0, ev.stderr
    result = json.loads(ev.stdout)
    assert result["episodes"] == 50 and 0.0 <= result["success_rate"] <= 1.0


def test_flags_follow_the_presets_algorithm(capsys):
    code, _, err = run_cli(capsys, "train", "pointreach-sac-her", "--double-q")
    assert code == 2 and "unknown option '--double-q'" in err  # a DQN flag, not SAC's
    code, _, err = run_cli(capsys, "train", "bitflip-her", "--algo", "sac")
    assert code == 2 and "needs continuous (Box) actions" in err


def test_multitask_train_then_eval_per_task_from_the_command_line(capsys, tmp_path):
    out = tmp_path / "mt"
    code, stdout, err = run_cli(capsys, "train", "pointreach-mt-ppo-onehot", "--out", str(out), "--total-steps", "4000",
                                "--eval-interval", "2000", "--eval-episodes", "2", "--no-progress", "--no-tensorboard")
    assert code == 0, err
    assert json.loads((out / "per_task_success.json").read_text())["episodes_per_task"] == 2
    code, stdout, err = run_cli(capsys, "eval", str(out), "--episodes", "3")
    result = json.loads(stdout)
    assert code == 0 and result["episodes"] == 3 and {"success/top-left", "success/centre"} <= set(result)
