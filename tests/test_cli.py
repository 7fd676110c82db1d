import json
import subprocess
import sys

import pytest

from helpers import run_cli
from taskrl.cli import main


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
        (["fly"], "allowed: train, eval, export, plot, presets, solve"),
        (["eval", "/nonexistent/run"], "not a run directory"),
        (["train", "mt10-sac-care", "--architecture", "transformer"], "'concat', 'film', 'care'"),
        (["train", "mt10-sac-care", "--num-envs", "12"], "--num-envs must be a multiple of the 10 tasks"),
        (["train", "mt10-ppo-onehot", "--estimator", "a2c"], "'ppo', 'reinforce'"),
        (["train", "pointreach-mt-sac-onehot", "--algo", "dqn"], "allowed: sac, ppo"),
        (["train", "bitflip-her", "--env", "my/Slider-v0"], "a gymnasium id goes to --env-id"),
        (["train", "bitflip-her", "--algo", "a2c"], "'dqn', 'qtopt', 'sac', 'td3', 'ppo'"),
        (["train", "pointreach-sac-her", "--env-id", "nobody/Nothing-v0"], "--env-module"),
        (["train", "pointreach-sac-her", "--env-module", "no_such_module_here"], "--env-module cannot import"),
        (["train", "grasp-qtopt-pixels", "--tolerance", "-0.1"], "--tolerance must be in (0, opening / 2)"),
        (["train", "grasp-qtopt-pixels", "--scripted-exploration", "0.5", "--scripted-steps", "-100"], "--scripted-steps"),
        (["demos", "collect", "pointreach-mt:,", "--episodes", "1", "--out", "/nonexistent/d"], "names no task"),
        (["plot", "/nonexistent/run", "--out", "/nonexistent/run/metrics.csv"], "--out must name an image file"),
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


@pytest.mark.slow
def test_train_then_eval_from_the_command_line(tmp_path):
    out = tmp_path / "cli-run"
    train = subprocess.run(
        [
            sys.executable,
            "-m",
            "taskrl.cli",
            "train",
            "bitflip-her",
            "--out",
            str(out),
            "--n-bits",
            "4",
            "--num-envs",
            "4",
            "--total-steps",
            "1500",
            "--eval-interval",
            "500",
            "--eval-episodes",
            "20",
            "--learning-starts",
            "100",
            "--hidden-sizes",
            "32",
            "32",
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert train.returncode == 0, train.stderr
    for name in ("config.json", "metrics.csv", "learning_curve.png"):
        assert (out / name).exists()
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    assert json.loads((out / "config.json").read_text())["dqn"]["hidden_sizes"] == [32, 32]
    header = (out / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"env_steps", "wall_seconds", "success_rate"} <= set(header)
    ev = subprocess.run(
        [sys.executable, "-m", "taskrl.cli", "eval", str(out), "--episodes", "20", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ev.returncode == 0, ev.stderr
    result = json.loads(ev.stdout)
    last = float((out / "metrics.csv").read_text().splitlines()[-1].split(",")[3])
    # the run's own evaluation seed and episode count: the loaded agent reproduces its last evaluation exactly
    assert result["episodes"] == 20 and result["success_rate"] == last


def test_a_rule_is_checked_in_one_place_ppo_runs_with_gamma_one(capsys, tmp_path):
    code, stdout, err = run_cli(
        capsys,
        "train",
        "bitflip-her",
        "--algo",
        "ppo",
        "--gamma",
        "1.0",
        "--n-bits",
        "4",
        "--num-envs",
        "4",
        "--rollout-steps",
        "8",
        "--total-steps",
        "64",
        "--eval-episodes",
        "4",
        "--out",
        str(tmp_path / "ppo"),
        "--no-progress",
        "--no-tensorboard",
    )
    assert code == 0, err
    assert "her=future) is off" in err  # what switching to an on-policy algorithm changed, said
    saved = json.loads((tmp_path / "ppo" / "config.json").read_text())
    assert saved["ppo"]["gamma"] == 1.0 and saved["replay"]["her"] == "none"
    code, _, err = run_cli(capsys, "train", "bitflip-her", "--algo", "ppo", "--her", "future", "--out", str(tmp_path / "x"))
    assert code == 2 and "--her ppo learns on-policy" in err  # asked for explicitly: refused, one line


def test_algo_on_a_preset_keeps_shared_settings_and_uses_its_own_exploration(capsys, tmp_path):
    code, _, err = run_cli(
        capsys,
        "train",
        "pointreach-sac-her",
        "--algo",
        "td3",
        "--total-steps",
        "64",
        "--eval-episodes",
        "4",
        "--out",
        str(tmp_path / "td3"),
        "--no-progress",
        "--no-tensorboard",
    )
    assert code == 0, err
    assert "note: --algo td3: kept lr=0.001, gamma=0.95, hidden_sizes=(64, 64) from sac" in err
    td3 = json.loads((tmp_path / "td3" / "config.json").read_text())["td3"]
    assert (td3["noise_std"], td3["random_action_prob"], td3["lr"]) == (0.1, 0.0, 0.001)


def test_help_lists_the_env_families_and_the_active_sections_settings(capsys):
    with pytest.raises(SystemExit):
        main(["train", "mt10-sac-care", "--help"])
    out = capsys.readouterr().out
    assert "--task " in out and "--max-episode-steps" in out and "--care-encoders" in out  # Meta-World's and SAC's
    assert "--n-bits" not in out  # bit flipping's, not this run's
    assert "gym (any gymnasium environment" in " ".join(out.split())


def test_flags_follow_the_presets_algorithm(capsys):
    code, _, err = run_cli(capsys, "train", "pointreach-sac-her", "--double-q")
    assert code == 2 and "unknown option '--double-q'" in err  # a DQN flag, not SAC's
    code, _, err = run_cli(capsys, "train", "bitflip-her", "--algo", "sac")
    assert code == 2 and "needs continuous (Box) actions" in err


@pytest.mark.slow
def test_multitask_train_then_eval_per_task_from_the_command_line(capsys, tmp_path):
    out = tmp_path / "mt"
    code, stdout, err = run_cli(
        capsys,
        "train",
        "pointreach-mt-ppo-onehot",
        "--out",
        str(out),
        "--total-steps",
        "4000",
        "--eval-interval",
        "2000",
        "--eval-episodes",
        "2",
        "--no-progress",
        "--no-tensorboard",
    )
    assert code == 0, err
    assert json.loads((out / "per_task_success.json").read_text())["episodes_per_task"] == 2
    code, stdout, err = run_cli(capsys, "eval", str(out), "--episodes", "3", "--json")
    result = json.loads(stdout)
    assert code == 0 and result["episodes"] == 3 and {"success/top-left", "success/centre"} <= set(result)


def test_files_in_the_way_are_one_line_and_leave_nothing_behind(capsys, tmp_path):
    """A file where a folder goes, a folder that is not a run, a name too long, an empty sentence: one line, exit 2."""
    (tmp_path / "file").write_text("")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "config.json").write_text('{"a": 1}')
    (foreign / "metrics.csv").write_text("x,y\n1,2\n")
    for args, expected in (
        (["demos", "collect", "pointreach-mt", "--episodes", "1", "--out", str(tmp_path / "file")], "is a file"),
        (["plot", str(foreign), "--out", str(tmp_path / "p.png")], "is not a run directory"),
        (["eval", str(foreign), "--task", " "], "--task must be a sentence"),
        (["export", str(foreign), "--out", str(tmp_path / ("a" * 300))], "--out cannot use"),
    ):
        code, _, err = run_cli(capsys, *args)
        assert code == 2 and len(err.strip().splitlines()) == 1 and expected in err, (args, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "foreign"]


def test_pixels_from_an_env_that_does_not_render_are_one_line(capsys, tmp_path):
    code, _, err = run_cli(
        capsys,
        "train",
        "pointreach-sac-her",
        "--env-id",
        "testenvs/SlideTo-v0",
        "--env-module",
        "test_custom_envs",
        "--observation",
        "pixels",
        "--out",
        str(tmp_path / "run"),
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and "rgb_array" in err, err
    assert not (tmp_path / "run").exists()


def test_train_seeds_checks_its_seeds_before_any_run():
    import taskrl
    from taskrl.errors import ConfigError

    for seeds in (3, [0, "x"], [0, 0], [-1]):
        with pytest.raises(ConfigError, match="seeds"):
            taskrl.train_seeds("bitflip-her", seeds=seeds)
