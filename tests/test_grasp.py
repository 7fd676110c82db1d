"""The grasp env: its hold rule, episodes, object sets, camera and success detector."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import taskrl  # noqa: F401  (registers taskrl/Grasp-v0)
from taskrl.envs.grasp import COLOURS, FLOOR, GRASP_OBJECT_SETS, SHAPES, Grasp, GraspSettings, scripted_attempts
from taskrl.errors import ConfigError

CLOSE = torch.tensor([[0.0, 0.0, 0.0, 1.0]])


def one_object(shape: str, half: tuple[float, float], angle: float = 0.0, **settings) -> Grasp:
    """A bin with one object of ``shape`` at the centre, turned by ``angle``."""
    env = Grasp(GraspSettings(num_objects=1, **settings), num_envs=1, seed=0)
    env.reset(seed=0)
    env.shape[:] = SHAPES.index(shape)
    env.half[:] = torch.tensor(half)
    env.centre[:] = 0.5
    env.angle[:] = angle
    return env


def attempt(env: Grasp, at: tuple[float, float], yaw: float):
    env.gripper[:] = torch.tensor(at)
    env.yaw[:] = yaw
    return env.step(CLOSE)


@pytest.mark.parametrize("objects", list(GRASP_OBJECT_SETS))
def test_the_gymnasium_env_passes_the_checker(objects):
    env = gym.make("taskrl/Grasp-v0", objects=objects)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert obs["image"].shape == (64, 64, 3) and obs["image"].dtype.name == "uint8"


def test_a_bar_is_held_across_the_fingers_only_and_on_its_spine():
    bar = (0.1, 0.025)  # 0.2 long: wider than the 0.14 opening along it
    # the jaws close along the gripper's yaw: across the bar (yaw = bar + 90 degrees) it fits
    _, reward, terminated, _, info = attempt(one_object("bar", bar), (0.5, 0.5), math.pi / 2)
    assert reward.item() == 1.0 and terminated.item() and info["is_success"].item()
    _, reward, terminated, _, _ = attempt(one_object("bar", bar), (0.5, 0.5), 0.0)  # along the bar: too long
    assert reward.item() == 0.0 and terminated.item()
    assert attempt(one_object("bar", bar), (0.56, 0.5), math.pi / 2)[1].item() == 1.0  # elsewhere on the spine
    assert attempt(one_object("bar", bar), (0.5, 0.55), math.pi / 2)[1].item() == 1.0  # within the 0.06 tolerance
    assert attempt(one_object("bar", bar), (0.5, 0.57), math.pi / 2)[1].item() == 0.0  # off the spine


def test_a_disc_is_held_at_any_yaw_and_a_wide_square_only_turned_to_fit():
    """At the sizes the env samples: the smallest and largest squares (half-side 0.052 and 0.065) fit face on and not
    corner to corner; a disc at any yaw."""
    from taskrl.envs.grasp import SIZES

    for yaw in (0.0, 0.7, 1.9):
        assert attempt(one_object("disc", (0.05, 0.05)), (0.5, 0.5), yaw)[1].item() == 1.0
    for side in SIZES["square"][0]:
        square = (side, side)
        assert attempt(one_object("square", square), (0.5, 0.5), 0.0)[1].item() == 1.0
        assert attempt(one_object("square", square), (0.5, 0.5), math.pi / 4)[1].item() == 0.0
    for name in ("bar", "ellipse"):  # the shortest of each is longer than the opening: held only across
        (shortest, _), widths = SIZES[name]
        shape = (shortest, widths[0])
        assert attempt(one_object(name, shape), (0.5, 0.5), math.pi / 2)[1].item() == 1.0
        assert attempt(one_object(name, shape), (0.5, 0.5), 0.0)[1].item() == 0.0


def test_an_attempt_ends_at_the_close_or_unsolved_at_the_horizon():
    env = Grasp(GraspSettings(horizon=3), num_envs=4, seed=1)
    env.reset(seed=1)
    for step in range(1, 4):
        _, reward, terminated, truncated, info = env.step(torch.zeros(4, 4) - 0.5)  # never closes
        assert reward.eq(0).all() and not info["attempted"].any() and not truncated.any()
        assert terminated.all() == (step == 3)  # the time left is observed: running out is terminal
    assert env.t.eq(0).all()  # reset in the same step


def test_held_out_objects_share_no_shape_and_colour_pair_with_training_and_show_new_ones():
    train, held_out = set(GRASP_OBJECT_SETS["train"]), set(GRASP_OBJECT_SETS["held_out"])
    assert not train & held_out
    unseen = {c for s, c in held_out} - {c for s, c in train}
    env = Grasp(GraspSettings(objects="held_out", num_objects=8), num_envs=64, seed=0)
    env.reset(seed=0)
    colours = {tuple(c) for c in env.colour.reshape(-1, 3).int().tolist()}
    assert {COLOURS[c] for c in unseen} & colours
    assert any(SHAPES[int(s)] == "ellipse" for s in env.shape.reshape(-1))


def test_the_camera_shows_each_object_in_its_colour_and_the_gripper():
    env = one_object("disc", (0.06, 0.06))
    env.colour[:], env.packed[:] = torch.tensor(COLOURS["blue"], dtype=torch.float32), 40 | 80 << 8 | 220 << 16
    env.gripper[:] = torch.tensor([0.2, 0.8])
    env.yaw[:] = 0.0
    image = env.render()[0]
    assert tuple(image[32, 32].tolist()) == COLOURS["blue"]  # the object's centre (row = y, column = x)
    assert tuple(image[2, 60].tolist()) == FLOOR
    finger = image[int(0.8 * 64), int(0.13 * 64)]  # left finger, 0.07 from the gripper's centre along x
    assert tuple(finger.tolist()) == (40, 40, 40)


def test_the_detector_reads_holds_from_the_two_pictures_and_can_label_the_reward():
    env = Grasp(GraspSettings(reward="detector"), num_envs=1024, seed=3)
    env.reset(seed=3)
    g = torch.Generator().manual_seed(0)
    env.gripper = env.centre[:, 0] + 0.01 * torch.randn(1024, 2, generator=g)
    env.yaw = math.pi * torch.rand(1024, generator=g)
    _, reward, _, _, info = env.step(CLOSE.expand(1024, 4))
    held, detected = info["is_success"], info["detected"]
    assert 0.3 < held.float().mean() < 0.95  # both outcomes occur
    precision = (held & detected).sum() / detected.sum()
    recall = (held & detected).sum() / held.sum()
    assert precision > 0.98 and recall > 0.98
    assert torch.equal(reward, detected.float())  # trained on the detector's labels
    lit = info["bin_before"].float().mean((1, 2, 3)) / info["bin_after"].float().mean((1, 2, 3))
    assert lit.std() > 0.05  # the two pictures are lit differently, so a plain difference would not do


def test_bad_settings_name_the_setting():
    with pytest.raises(ConfigError, match="objects"):
        Grasp(GraspSettings(objects="unseen"))
    with pytest.raises(ConfigError, match="image_size"):
        Grasp(GraspSettings(image_size=8))
    with pytest.raises(ConfigError, match="tolerance"):
        Grasp(GraspSettings(tolerance=-0.1))


def _scripted_success(env: Grasp, **kwargs) -> float:
    attempts, held = scripted_attempts(env, **kwargs)
    return held / attempts


def test_the_scripted_grasp_holds_what_it_aims_at_and_its_aim_noise_makes_it_an_explorer():
    assert _scripted_success(Grasp(GraspSettings(), num_envs=500, seed=0), aim_noise=0.0) >= 0.95
    assert 0.15 <= _scripted_success(Grasp(GraspSettings(), num_envs=500, seed=0)) <= 0.35  # QT-Opt's: 15-30%
    env = Grasp(GraspSettings(), num_envs=8, seed=0)
    obs = env.reset(seed=0)
    state = env.generator.get_state()
    env.scripted_action(obs)
    assert torch.equal(env.generator.get_state(), state)  # the env's own random stream is untouched


@pytest.mark.timeout(300)
def test_scripted_exploration_acts_its_share_of_episodes_until_its_last_step(tmp_path):
    from helpers import small_run

    def train_success(out, **settings) -> float:
        run = small_run(
            "grasp-qtopt-pixels",
            tmp_path / out,
            total_steps=800,
            learning_starts=10_000,
            eval_interval=800,
            eval_episodes=2,
            image_size=16,
            threads=1,
            **settings,
        )
        return run.metrics["train_success"]

    assert train_success("all", scripted_exploration=1.0) > 0.15  # the scripted grasp's rate, not random actions'
    assert train_success("none", scripted_exploration=0.0) < 0.11  # random actions hold in 5-6% of attempts
    assert train_success("stopped", scripted_exploration=1.0, scripted_steps=16) < 0.11  # none after the first step


def test_scripted_exploration_is_refused_where_the_env_has_no_scripted_policy(tmp_path):
    from taskrl.overrides import with_overrides
    from taskrl.plan import validate
    from taskrl.presets import preset_config

    with pytest.raises(ConfigError, match="scripted_exploration.*no scripted policy.*grasp"):
        validate(with_overrides(preset_config("pointreach-sac-her"), {"scripted_exploration": 0.5}))
    with pytest.raises(ConfigError, match="scripted_exploration.*distributed"):
        validate(with_overrides(preset_config("grasp-qtopt-pixels"), {"scripted_exploration": 0.5, "distributed": True}))
    validate(with_overrides(preset_config("grasp-qtopt-pixels"), {"scripted_exploration": 0.5}))


def tiny_grasp_run(out, **settings):
    """``grasp-qtopt-pixels`` for 32 env steps at 16x16, evaluated once on 2 attempts."""
    from helpers import small_run

    return small_run(
        "grasp-qtopt-pixels",
        out,
        total_steps=32,
        learning_starts=16,
        eval_interval=32,
        eval_episodes=2,
        image_size=16,
        **settings,
    )


def test_a_grasp_run_is_evaluated_on_its_held_out_objects_from_the_cli(tmp_path, monkeypatch):
    """``taskrl eval RUN --held-out`` builds the run's env on the held-out objects (and plain eval on its own)."""
    import json

    from helpers import cli
    from taskrl import loading

    tiny_grasp_run(tmp_path / "run")
    built = []
    make = loading.make_env
    monkeypatch.setattr(
        loading, "make_env", lambda config, *a, **k: built.append(config.env_settings.objects) or make(config, *a, **k)
    )
    for held_out in (True, False):
        result = loading.evaluate_run(tmp_path / "run", episodes=2, held_out=held_out)
        assert result["episodes"] == 2
    assert built == ["held_out", "train"]
    done = cli("eval", str(tmp_path / "run"), "--held-out", "--episodes", "2", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["episodes"] == 2


def test_the_failure_sorting_tells_a_miss_of_yaw_from_a_miss_of_position_and_no_close():
    """``benchmarks/grasp_failures.py``: one bar at the centre in four bins, closed across it, along it, beside it,
    and never. Mutation: the object's fit left out of the sorting (every close over a spine counted held) fails."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from grasp_failures import OUTCOMES, _Sorting
    finally:
        sys.path.pop(0)
    env = Grasp(GraspSettings(num_objects=1), num_envs=4, seed=0)
    sorting = _Sorting(env)
    sorting.reset(seed=0)
    env.shape[:], env.half[:], env.centre[:], env.angle[:] = SHAPES.index("bar"), torch.tensor([0.1, 0.025]), 0.5, 0.0
    env.gripper[:] = torch.tensor([[0.5, 0.5], [0.5, 0.5], [0.5, 0.8], [0.5, 0.5]])
    env.yaw[:] = torch.tensor([math.pi / 2, 0.0, math.pi / 2, 0.0])
    for _ in range(env.horizon):
        sorting.step(torch.tensor([[0.0, 0.0, 0.0, 1.0]] * 3 + [[0.0, 0.0, 0.0, -1.0]]))
    assert [OUTCOMES[i] for i in sorting.outcome.tolist()] == ["held", "yaw", "position", "no close"]
    assert abs(sorting.miss_pixels[0] - 0.3 * 64) < 0.5  # 0.3 of the bin off the bar's centre, across it
    (shape, degrees), *_ = sorting.yaw_misses
    # along the bar, the jaws must turn to within about 28.7 degrees of across it: 61.3 degrees away
    assert shape == SHAPES.index("bar") and 60.0 < degrees < 63.0


def test_the_glimpse_turns_the_picture_into_the_jaws_frame():
    """`GlimpseInput` at the pose the bin declares: a bar under the gripper lies along the glimpse's rows when it fits
    across the jaws and along its columns when it lies along them, centred, whatever the yaw. Mutation: the turn's sign
    flipped (the picture turned the other way) fails."""
    from taskrl.encoders import GlimpseInput
    from taskrl.envs.grasp import FLOOR
    from taskrl.types import PictureState

    floor = torch.tensor(FLOOR).float()[:, None, None] / 255
    for yaw in (0.3, 2.2):
        for across in (True, False):
            env = one_object("bar", (0.1, 0.02), angle=yaw + (math.pi / 2 if across else 0.0))
            env.gripper[:], env.yaw[:] = 0.5, yaw
            state = PictureState(env._obs()["observation"], env.render(gripper=False)[:, None])
            glimpse = GlimpseInput(5, (64, 64, 3), "conv", 50, env.picture_pose).glimpse(state)[0] + 0.5  # [3, 32, 32]
            rows, cols = torch.nonzero((glimpse - floor).abs().sum(0) > 0.3, as_tuple=True)
            long, short = (rows, cols) if across else (cols, rows)
            assert long.float().std() > 3 * short.float().std() and abs(float(short.float().mean()) - 15.5) < 1


def test_qtopt_with_the_glimpse_reads_the_gripper_pose_as_the_env_gives_it():
    """``--fusion glimpse`` built as a run builds it: the pose's columns reach the network unnormalised (the other
    columns normalised), so the glimpse is the one the env's own pose gives; a shift without the pose moved with it,
    or an env that declares no pose, is refused naming the setting. Mutation: the pose's columns normalised like the
    rest (no ``raw_columns``) fails it."""
    from taskrl.encoders import GlimpseInput
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.types import PictureState
    from taskrl.wiring.parts import make_agent, make_env

    settings = {"image_size": 16, "hidden_sizes": (8,), "num_envs": 8, "fusion": "glimpse", "shift_coordinates": True}
    config = with_overrides(preset_config("grasp-qtopt-pixels"), settings)
    env = make_env(config, "cpu")
    agent = make_agent(config, env, torch.device("cpu"))
    net = agent.q.state_input
    assert isinstance(net, GlimpseInput) and net.pose.columns == (0, 1, 2, 3)
    for seed in range(3):
        agent.inputs.update_statistics(env.reset(seed=seed))
    obs = env.reset(seed=7)
    state = agent.inputs(obs)
    raw = obs["observation"].float()
    assert torch.equal(state.vector[:, :4], raw[:, :4]) and not torch.allclose(state.vector[:, 4], raw[:, 4])
    assert torch.equal(net.glimpse(state), net.glimpse(PictureState(raw, state.pictures)))
    with pytest.raises(ConfigError, match="shift_coordinates"):
        make_agent(with_overrides(config, {"shift_coordinates": False}), env, torch.device("cpu"))
    config = with_overrides(preset_config("pixelpush-sac-her"), {"algo": "qtopt", "fusion": "glimpse", "image_size": 16})
    with pytest.raises(ConfigError, match="fusion"):
        make_agent(config, make_env(config, "cpu"), torch.device("cpu"))


def test_an_exported_glimpse_policy_keeps_the_pose_and_acts_like_the_run(tmp_path):
    """``taskrl export`` of a ``--fusion glimpse`` run writes what the env declares about its pictures (the pose, the
    coordinates the shift moves), so ``load_policy`` builds the same network without the env and acts as the run's
    agent does. Mutation: the pose left out of ``policy.json`` fails it (the policy is refused)."""
    from taskrl.export import export_policy

    tiny_grasp_run(tmp_path / "run", hidden_sizes=(16,), fusion="glimpse", shift_coordinates=True)
    export_policy(tmp_path / "run", tmp_path / "policy")
    policy, agent = taskrl.load_policy(tmp_path / "policy"), taskrl.load(tmp_path / "run")
    assert policy.agent.q.state_input.pose == agent.q.state_input.pose
    obs = Grasp(GraspSettings(image_size=16), num_envs=4, seed=3).reset(seed=3)
    torch.manual_seed(0)
    mine = policy.predict({k: v.numpy() for k, v in obs.items()})
    torch.manual_seed(0)
    assert np.array_equal(mine, agent.act({k: v.numpy() for k, v in obs.items()}))
