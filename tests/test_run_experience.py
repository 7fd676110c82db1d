"""The run experience: logs without a terminal, names kept on resume, evaluation with intervals and
videos, policy export, settings files, many seeds and their comparison, TensorBoard between evaluations."""

import csv
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import taskrl
from helpers import cli, metrics, small_run
from taskrl.checkpoint import latest_checkpoint
from taskrl.cli import main
from taskrl.errors import ConfigError

TINY = ["--n-bits", "6", "--total-steps", "3000", "--eval-interval", "1000", "--eval-episodes", "20", "--no-tensorboard"]


@pytest.mark.slow
def test_without_a_terminal_a_run_prints_one_line_per_evaluation_and_keeps_its_name_on_resume(tmp_path):
    out = tmp_path / "run"
    first = cli("train", "bitflip-her", *TINY, "--out", str(out))  # stderr is a pipe: no terminal
    assert first.returncode == 0, first.stderr
    lines = [line for line in first.stderr.splitlines() if line.startswith("bitflip-her  step ")]
    assert len(lines) == len(metrics(out)) >= 4  # one per evaluation, each flushed as it happens
    assert all("success" in line and "steps/s" in line and "ETA" in line for line in lines)
    again = cli("train", "--resume", str(out), "--total-steps", "5000", "--no-tensorboard")
    assert again.returncode == 0, again.stderr
    resumed = [line for line in again.stderr.splitlines() if " step " in line and "ETA" in line]
    assert resumed and all(line.startswith("bitflip-her  step ") for line in resumed)  # not "bitflip-dqn"


def test_print_config_round_trips_through_config(tmp_path, capsys):
    assert main(["train", "pointreach-sac-her", "--lr", "3e-3", "--hidden-sizes", "32", "32", "--print-config"]) == 0
    printed = capsys.readouterr().out
    (tmp_path / "c.json").write_text(printed)
    assert main(["train", "--config", str(tmp_path / "c.json"), "--print-config"]) == 0
    assert capsys.readouterr().out == printed
    data = json.loads(printed)
    assert (data["sac"]["lr"], data["sac"]["hidden_sizes"], data["env"]) == (3e-3, [32, 32], "pointreach")
    (tmp_path / "flat.yaml").write_text("lr: 0.005\ngamma: 0.5\n")  # settings by name, under the flags
    assert main(["train", "bitflip-her", "--config", str(tmp_path / "flat.yaml"), "--gamma", "0.9", "--print-config"]) == 0
    dqn = json.loads(capsys.readouterr().out)["dqn"]
    assert (dqn["lr"], dqn["gamma"]) == (0.005, 0.9)


def test_a_list_of_numbers_setting_takes_negative_and_fractional_values_and_round_trips(tmp_path, capsys):
    """``cem.init_mean`` (``tuple[float, ...]``) from flags, through config.json, and emptied by the bare flag.
    Mutation: read as whole numbers like ``hidden_sizes`` -> -0.5 refused."""
    assert main(["train", "kukagrasp-qtopt", "--init-mean", "0", "0", "-0.5", "0.25", "--print-config"]) == 0
    printed = capsys.readouterr().out
    assert json.loads(printed)["qtopt"]["cem"]["init_mean"] == [0.0, 0.0, -0.5, 0.25]
    (tmp_path / "c.json").write_text(printed)
    assert main(["train", "--config", str(tmp_path / "c.json"), "--print-config"]) == 0
    assert capsys.readouterr().out == printed
    assert main(["train", "kukagrasp-qtopt", "--init-mean", "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out)["qtopt"]["cem"]["init_mean"] == []
    (tmp_path / "bad.json").write_text(printed.replace("0.25", '"up"'))
    assert main(["train", "--config", str(tmp_path / "bad.json"), "--print-config"]) == 2
    assert "--init-mean must be a list of numbers" in capsys.readouterr().err


def test_help_shows_the_presets_values_and_budget_warnings_are_said(capsys):
    with pytest.raises(SystemExit):
        main(["train", "pointreach-sac-her", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "[here: 0.001]" in text and "[here: 0.95]" in text  # the preset's lr and gamma
    assert main(["train", "bitflip-her", "--learning-starts", "5000", "--total-steps", "1000", "--print-config"]) == 0
    assert "warning: learning_starts=5,000 >= total_steps=1,000" in capsys.readouterr().err


@pytest.fixture(scope="module")
def bitflip_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "bitflip"
    assert main(["train", "bitflip-her", *TINY, "--out", str(out), "--no-progress", "--checkpoint-interval", "1000"]) == 0
    return out


def test_eval_gives_intervals_the_checkpoint_step_and_older_checkpoints(bitflip_run, capsys):
    assert main(["eval", str(bitflip_run), "--episodes", "50", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    lo, hi = result["success_ci95"]
    assert (
        lo <= result["success_rate"] <= hi
        and hi - lo > 0
        and result["checkpoint_step"] == int(metrics(bitflip_run)[-1]["env_steps"])
    )
    rlo, rhi = result["eval_return_ci95"]
    assert rlo < result["eval_return"] < rhi
    kept = sorted(int(p.name[5:17]) for p in (bitflip_run / "checkpoints").glob("step_*"))
    assert main(["eval", str(bitflip_run), "--episodes", "20", "--json", "--checkpoint", str(kept[0])]) == 0
    assert json.loads(capsys.readouterr().out)["checkpoint_step"] == kept[0]
    assert main(["eval", str(bitflip_run), "--episodes", "20"]) == 0  # a table by default
    assert "95% interval" in capsys.readouterr().out


def test_eval_writes_a_playable_video_of_a_native_env(bitflip_run, capsys):
    import imageio.v2 as imageio

    assert main(["eval", str(bitflip_run), "--episodes", "5", "--video", "1", "--json"]) == 0
    video = Path(json.loads(capsys.readouterr().out)["videos"][0])
    assert video.parent == bitflip_run / "videos" and video.suffix == ".mp4"
    frames = [frame for frame in imageio.get_reader(video)]  # (list() asks for a length ffmpeg streams lack)
    assert len(frames) >= 2 and frames[0].ndim == 3  # a first frame and at least one step


@pytest.mark.slow
def test_eval_writes_a_playable_video_of_fetchreach(tmp_path):
    out = tmp_path / "fetch"
    trained = cli(
        "train",
        "fetchreach-sac-her",
        "--total-steps",
        "200",
        "--learning-starts",
        "100",
        "--eval-episodes",
        "2",
        "--out",
        str(out),
        "--no-progress",
        "--no-tensorboard",
    )
    assert trained.returncode == 0, trained.stderr
    evaluated = cli("eval", str(out), "--episodes", "2", "--video", "1", "--json")
    if evaluated.returncode != 0 and "cannot render here" in evaluated.stderr:
        pytest.skip(f"MuJoCo cannot render on this machine: {evaluated.stderr.strip()[-200:]}")
    assert evaluated.returncode == 0, evaluated.stderr
    import imageio.v2 as imageio

    frames = [frame for frame in imageio.get_reader(json.loads(evaluated.stdout)["videos"][0])]
    assert len(frames) == 51 and frames[0].shape[2] == 3  # FetchReach's 50 steps and the first frame


@pytest.mark.parametrize(
    "preset, env_id, extra, flags",
    [
        ("bitflip-her", "taskrl/BitFlip-v0", {"n_bits": 6}, []),  # DQN
        ("pointreach-mt-sac-onehot", "taskrl/MultiTaskPointReach-v0", {}, []),  # multi-task SAC
        ("pointreach-qtopt-her", "taskrl/PointReach-v0", {}, []),  # QT-Opt
        ("pointreach-sac-her", "taskrl/PointReach-v0", {}, ["--algo", "td3"]),  # TD3
        ("pointreach-mt-ppo-onehot", "taskrl/MultiTaskPointReach-v0", {}, ["--rollout-steps", "16"]),  # PPO
    ],
)
@pytest.mark.slow
def test_an_exported_policy_acts_like_the_runs_agent(tmp_path, capsys, preset, env_id, extra, flags):
    import torch

    run = tmp_path / "run"
    settings = [f"--{k.replace('_', '-')}={v}" for k, v in extra.items()] + flags
    command = ["train", preset, *settings, "--total-steps", "2000", "--eval-episodes", "4", "--out", str(run)]
    assert main([*command, "--no-progress", "--no-tensorboard"]) == 0
    assert main(["export", str(run), "--out", str(tmp_path / "policy")]) == 0
    policy, agent = taskrl.load_policy(tmp_path / "policy"), taskrl.load(run)
    vec = gym.make_vec(env_id, num_envs=16, **extra)
    obs, _ = vec.reset(seed=3)

    def same(first, second):  # QT-Opt's greedy action is a CEM search: the same random state, the same action
        torch.manual_seed(0)
        a = np.asarray(first())
        torch.manual_seed(0)
        np.testing.assert_array_equal(a, np.asarray(second()))

    same(lambda: policy.predict(obs), lambda: agent.act(obs))  # a numpy batch in, numpy out
    single = {k: v[0] for k, v in obs.items()}
    same(lambda: policy.predict(single), lambda: agent.act(single))
    size = sum(f.stat().st_size for f in (tmp_path / "policy").iterdir())
    trained = latest_checkpoint(run / "checkpoints")  # after updates: the agent part holds its optimiser state
    assert size < (trained / "agent.safetensors").stat().st_size / 3  # no optimiser state, no target networks
    assert not any("replay" in f.name for f in (tmp_path / "policy").iterdir())
    vec.close()


@pytest.mark.slow
def test_many_seeds_into_one_folder_and_plot_matches_their_metrics(tmp_path, capsys):
    folder = tmp_path / "seeds"
    code = main(["train", "bitflip-her", "--seeds", "0", "1", "2", "--parallel", "2", *TINY, "--out", str(folder)])
    assert code == 0
    assert sorted(p.name for p in folder.iterdir() if p.is_dir()) == ["seed_0", "seed_1", "seed_2"]
    seeds = [json.loads((folder / f"seed_{s}" / "config.json").read_text())["seed"] for s in range(3)]
    assert seeds == [0, 1, 2]
    assert main(["plot", str(folder), "--out", str(tmp_path / "cmp.png"), "--threshold", "0.9"]) == 0
    assert (tmp_path / "cmp.png").stat().st_size > 10_000
    summary = list(csv.DictReader(open(tmp_path / "cmp.csv")))[0]
    finals = [float(metrics(folder / f"seed_{s}")[-1]["success_rate"]) for s in range(3)]
    bests = [max(float(r["success_rate"]) for r in metrics(folder / f"seed_{s}")) for s in range(3)]
    assert float(summary["final_success"]) == pytest.approx(sum(finals) / 3)
    assert float(summary["best_success"]) == pytest.approx(sum(bests) / 3)
    reached = [
        next((int(r["env_steps"]) for r in metrics(folder / f"seed_{s}") if float(r["success_rate"]) >= 0.9), None)
        for s in range(3)
    ]
    hit = sorted(r for r in reached if r is not None)
    assert summary["reached_0.9"] == f"{len(hit)}/3"
    if hit:
        assert float(summary["median_env_steps_to_threshold"]) == pytest.approx(
            hit[len(hit) // 2] if len(hit) % 2 else (hit[len(hit) // 2 - 1] + hit[len(hit) // 2]) / 2
        )


def test_train_seeds_in_python_trains_each_seed_in_turn_and_compares_them(tmp_path):
    small = {"n_bits": 4, "total_steps": 200, "eval_interval": 100, "eval_episodes": 5, "tensorboard": False}
    result = taskrl.train_seeds("bitflip-her", [3, 4], out=tmp_path / "seeds", **small)
    assert sorted(result.runs) == [3, 4] and not result.failed
    assert [run.config.seed for run in result.runs.values()] == [3, 4]
    assert [run.run_dir.name for run in result.runs.values()] == ["seed_3", "seed_4"]
    finals = [float(metrics(run.run_dir)[-1]["success_rate"]) for run in result.runs.values()]
    assert result.summary[0]["final_success"] == pytest.approx(sum(finals) / 2)
    assert result.plot.stat().st_size > 10_000
    with pytest.raises(ConfigError, match="seeds"):
        taskrl.train_seeds("bitflip-her", [1, 1], out=tmp_path / "twice", **small)
    with pytest.raises(ConfigError, match="lr"):  # checked before any run starts: nothing is written
        taskrl.train_seeds("bitflip-her", [1, 2], out=tmp_path / "bad", lr=-1.0, **small)
    assert not (tmp_path / "bad").exists() and not (tmp_path / "twice").exists()


@pytest.mark.slow
def test_tensorboard_gets_training_scalars_between_evaluations(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run = taskrl.train(
        "bitflip-her",
        out=tmp_path / "run",
        n_bits=6,
        total_steps=6000,
        eval_interval=3000,
        eval_episodes=10,
        tensorboard_interval=1000,
    )
    events = EventAccumulator(str(run.run_dir / "tensorboard")).Reload()
    steps = [e.step for e in events.Scalars("train/loss")]
    evaluations = [e.step for e in events.Scalars("taskrl/success_rate")]
    assert len(steps) >= 4 > len(evaluations) - 1 and steps == sorted(set(steps))


@pytest.mark.slow
def test_eval_writes_a_video_of_a_metaworld_task(tmp_path):
    out = tmp_path / "mt1"
    trained = cli(
        "train",
        "mt1-reach-sac",
        "--total-steps",
        "100",
        "--learning-starts",
        "50",
        "--max-episode-steps",
        "20",
        "--eval-episodes",
        "1",
        "--num-envs",
        "1",
        "--out",
        str(out),
        "--no-progress",
        "--no-tensorboard",
    )
    assert trained.returncode == 0, trained.stderr
    evaluated = cli("eval", str(out), "--episodes", "1", "--video", "1", "--json")
    if evaluated.returncode != 0 and "cannot render here" in evaluated.stderr:
        pytest.skip(f"MuJoCo cannot render on this machine: {evaluated.stderr.strip()[-200:]}")
    assert evaluated.returncode == 0, evaluated.stderr
    import imageio.v2 as imageio

    video = Path(json.loads(evaluated.stdout)["videos"][0])
    frames = [frame for frame in imageio.get_reader(video)]
    assert video.name == "episode_000_reach.mp4" and len(frames) == 21 and frames[10].std() > 10  # a scene, not black


def test_a_run_started_from_another_runs_agent_begins_where_it_ended_and_refuses_one_that_does_not_fit(
    bitflip_run, tmp_path, capsys
):
    trained = float(metrics(bitflip_run)[-1]["success_rate"])
    no_update = ["--total-steps", "8", "--learning-starts", "100000", "--eval-episodes", "50", "--no-progress"]
    tiny = [*TINY[:2], *TINY[-1:], *no_update]
    assert main(["train", "bitflip-her", *tiny, "--out", str(tmp_path / "started"), "--init-from", str(bitflip_run)]) == 0
    last = int(metrics(bitflip_run)[-1]["env_steps"])
    assert f"the agent starts from {bitflip_run}'s last checkpoint ({last:,} env steps" in capsys.readouterr().err
    assert main(["train", "bitflip-her", *tiny, "--out", str(tmp_path / "fresh")]) == 0
    started, fresh = (float(metrics(tmp_path / name)[0]["success_rate"]) for name in ("started", "fresh"))
    assert trained >= 0.8 and started >= 0.8 and fresh <= 0.3  # before any update of its own: the trained agent
    assert int(metrics(tmp_path / "started")[-1]["updates"]) == 0  # counters start at 0
    for bad, why in (
        (["--n-bits", "7"], "does not fit this run's networks"),  # another input size
        (["--init-from", str(tmp_path / "nothing")], "holds no run to start from"),
    ):
        args = ["train", "bitflip-her", *no_update, "--init-from", str(bitflip_run), *bad, "--out", str(tmp_path / "bad")]
        assert main(args) == 2
        said = [line for line in capsys.readouterr().err.splitlines() if "error:" in line]
        assert len(said) == 1 and "--init-from" in said[0] and why in said[0]
        assert not (tmp_path / "bad").exists()  # nothing of a refused run stays behind


def test_an_offline_run_leaves_its_stored_data_out_of_its_checkpoints_and_says_where_the_data_are(tmp_path):
    quick = dict(eval_interval=10**6, eval_episodes=2, tensorboard=False, threads=1)
    small_run("bitflip-her", tmp_path / "source", n_bits=6, total_steps=600, learning_starts=10**6, **quick)
    offline = dict(n_bits=6, offline=True, offline_data=str(tmp_path / "source"), total_steps=20, **quick)
    run = small_run("bitflip-her", tmp_path / "offline", **offline)
    assert run.metrics["replay_transitions"] > 0
    assert not list((run.run_dir / "checkpoints").glob("*/replay.*"))  # the source's data, unchanged, not copied
    with pytest.raises(ConfigError) as error:  # an offline run is no data source: it names the one it read
        small_run("bitflip-her", tmp_path / "chained", **{**offline, "offline_data": str(tmp_path / "offline")})
    assert error.value.field == "offline_data" and f"use --offline-data {tmp_path / 'source'}" in error.value.message
