"""KukaGrasp-v0, the pybullet grasping benchmark: its object split, episodes, settling, random policy and runs."""

from __future__ import annotations

import glob
import os

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import taskrl  # noqa: F401  (registers taskrl/KukaGrasp-v0)
from taskrl.envs.kuka_grasp import (
    DROP_HEIGHT,
    SETTLE_STEPS,
    STAGGER_STEPS,
    STEPS,
    KukaGraspEnv,
    KukaGraspSettings,
    KukaGraspVectorEnv,
    object_files,
    random_grasp_action,
)
from taskrl.errors import ConfigError

pybullet_data = pytest.importorskip("pybullet_data", reason="the grasp extra (pybullet) is installed by `make test`")
UP = np.array([0.0, 0.0, 1.0, 0.0], dtype=np.float32)
DOWN = np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32)


def until_the_end(env: KukaGraspEnv, action: np.ndarray) -> tuple[int, float, dict]:
    """Steps of one episode acting ``action`` throughout: (steps, last reward, last info)."""
    for step in range(1, STEPS + 1):
        _, reward, terminated, truncated, info = env.step(action)
        assert not truncated
        if terminated:
            return step, reward, info
    raise AssertionError("the episode did not end after 15 steps")


def test_the_test_objects_are_held_out_for_real_where_the_benchmarks_pattern_drew_them_for_training():
    train, test = object_files("train"), object_files("test")
    assert len(train) == 900 and len(test) == 100 and not set(train) & set(test)
    assert all(os.path.basename(os.path.dirname(f)).endswith("0") for f in test)
    # the benchmark's training pattern: glob reads [^0] as "^ or 0", so it matched the test objects
    upstream = sorted(glob.glob(os.path.join(pybullet_data.getDataPath(), "random_urdfs", "*[^0]", "*.urdf")))
    assert upstream == test


def test_objects_are_drawn_from_the_split_and_redrawn_every_few_episodes():
    env = KukaGraspEnv(objects="test", redraw_every=2)
    try:
        drawn = [tuple(env.reset(seed=None if k else 0)[1]["objects"]) for k in range(4)]
    finally:
        env.close()
    assert all(name.endswith("0") for names in drawn for name in names)
    assert drawn[0] == drawn[1] and drawn[2] == drawn[3] and drawn[1] != drawn[2]


def test_the_same_seed_gives_the_same_episode():
    first, second = KukaGraspEnv(), KukaGraspEnv()
    try:
        a, info_a = first.reset(seed=5)
        b, info_b = second.reset(seed=5)
        assert info_a["objects"] == info_b["objects"]
        assert np.array_equal(a["image"], b["image"]) and np.allclose(a["observation"], b["observation"])
        c, _ = second.reset(seed=6)
        assert not np.array_equal(a["image"], c["image"])
    finally:
        first.close()
        second.close()


def test_an_episode_ends_at_a_grasp_or_unsolved_after_fifteen_steps():
    env = KukaGraspEnv()
    try:
        env.reset(seed=0)
        obs, *_ = env.step(UP)
        assert obs["observation"][4] == pytest.approx(1 - 1 / STEPS)  # the share of steps left
        steps, reward, info = until_the_end(env, UP)  # moving up never reaches the grasp height
        assert steps == STEPS - 1 and reward == 0.0 and not info["attempted"]
        env.reset(seed=0)
        steps, _, info = until_the_end(env, DOWN)  # moving down grasps within a few steps
        assert info["attempted"] and steps <= 6
    finally:
        env.close()


def test_settling_until_at_rest_lands_the_objects_where_the_definitions_settling_does():
    """The same drops settled both ways end within 2 cm of each other on average (the full check, with the
    success rates, is ``benchmarks/kuka_grasp.py settle``)."""
    ends, steps = {}, {}
    for settle in ("rest", "definition"):
        env = KukaGraspEnv(settle=settle)
        try:
            env.reset(seed=11)
            env.np_random = np.random.default_rng(3)  # the same drop poses for both
            steps[settle] = env.settle_objects(env.drop_poses(), settle)
            ends[settle] = env.object_positions()
        finally:
            env.close()
    assert steps["definition"] == 2500 and steps["rest"] < 2000
    assert np.linalg.norm(ends["rest"] - ends["definition"], axis=1).mean() < 0.02


def test_staggered_settling_drops_every_object_in_turn_and_lets_them_all_come_to_rest_in_the_tray():
    """Each object dropped 60 steps after the one before, then all simulated until at rest: every object leaves its
    parking place for the tray. Where they end is chaotic (two settlings of the same drops differ by centimetres), so
    its match with the definition's is measured over many drops, with the random policy's success, by
    ``benchmarks/kuka_grasp.py settle``. Mutation: all objects dropped at once (no wait) fails."""
    env = KukaGraspEnv(settle="staggered")
    try:
        env.reset(seed=11)
        env.np_random = np.random.default_rng(3)
        steps = env.settle_objects(env.drop_poses(), "staggered")
        ends = env.object_positions()
    finally:
        env.close()
    assert 5 * STAGGER_STEPS <= steps <= 5 * STAGGER_STEPS + SETTLE_STEPS
    assert ((ends[:, 0] > 0.35) & (ends[:, 0] < 0.85) & (np.abs(ends[:, 1]) < 0.3) & (ends[:, 2] < DROP_HEIGHT)).all()


def play_episodes(env: KukaGraspEnv, seed: int, episodes: int) -> list[tuple]:
    """Episodes acting DOWN throughout after one seeded reset: (objects, first picture, first object positions, reward)."""
    found = []
    for k in range(episodes):
        obs, info = env.reset(seed=seed if k == 0 else None)
        start = (info["objects"], obs["image"].copy(), env.object_positions())
        _, reward, _ = until_the_end(env, DOWN)
        found.append((*start, reward))
    return found


def test_an_episode_prepared_ahead_in_the_spare_simulation_is_the_one_reset_in_place_gives():
    """``reset_ahead`` settles the next episode in a second simulation in the background, from the same draws: the same
    objects, the same first pictures bit for bit, the same rewards. Mutation: the prepared simulation not handed over
    (the episode played in the old one) -> the objects differ."""
    found = {}
    for ahead in (False, True):
        env = KukaGraspEnv(reset_ahead=ahead)
        try:
            found[ahead] = play_episodes(env, seed=3, episodes=3)
        finally:
            env.close()
        assert env._preparing is None  # closing stops the background thread
    for (names, picture, positions, reward), (names_ahead, picture_ahead, positions_ahead, reward_ahead) in zip(
        found[False], found[True]
    ):
        assert names == names_ahead and reward == reward_ahead
        assert np.array_equal(picture, picture_ahead) and np.array_equal(positions, positions_ahead)
    assert len({tuple(names) for names, *_ in found[True]}) == 3


def test_the_arm_is_out_of_the_tray_while_the_next_objects_drop():
    """A missed grasp's lift stops with the gripper low in the tray; the next reset moves the arm back to its rest pose
    before dropping the objects (the definition's reset loads the arm there). Mutation: the arm reset only after the
    drops -> the objects fall onto the gripper left in the tray."""
    env = KukaGraspEnv(reset_ahead=False)
    heights = []
    settle = env._scene.settle_objects
    try:
        env._scene.settle_objects = lambda *a: heights.append(env.gripper_position()[2]) or settle(*a)
        env.reset(seed=3)
        _, reward, info = until_the_end(env, DOWN)
        assert reward == 0 and info["lift_failed_at"] > 0 and env.gripper_position()[2] < 0.2  # left low
        env.reset()
    finally:
        env.close()
    assert len(heights) == 2 and min(heights) > 0.3


def test_the_random_policy_moves_down_nine_times_in_ten():
    action = random_grasp_action(torch.Generator().manual_seed(0), 20_000)
    down = (action[:, 2] == -1).float().mean()
    assert 0.88 < down < 0.92 and action.abs().max() <= 1
    assert random_grasp_action(torch.Generator().manual_seed(0), 5, height_hack=True).shape == (5, 3)


def test_bad_settings_name_the_setting():
    bad_settings = (
        (dict(objects="unseen"), "objects"),
        (dict(redraw_every=0), "redraw_every"),
        (dict(settle="x"), "settle"),
        (dict(lift="early"), "lift"),
    )
    for bad, name in bad_settings:
        with pytest.raises(ConfigError, match=name):
            KukaGraspSettings(**bad).validate()


@pytest.mark.slow
def test_a_lift_stopped_once_the_grasp_has_failed_gives_the_full_lifts_reward_in_fewer_steps():
    """The same random grasps (seeded episodes: failures and successes) with the full lift and the one stopped once the
    fingers have shut on nothing: the same rewards, every failure certain long before the lift's end and no success
    ever called failed (the check over hundreds of grasps is ``benchmarks/kuka_grasp.py lift``)."""
    found = {}
    for lift in ("definition", "decided"):
        env, found[lift] = KukaGraspEnv(lift=lift), []
        try:
            for seed in range(6):
                env.reset(seed=seed)  # a fresh simulation: the same episode in both
                generator = torch.Generator().manual_seed(seed)
                for _ in range(STEPS):
                    _, reward, terminated, _, info = env.step(random_grasp_action(generator, 1)[0].numpy())
                    if terminated:
                        break
                found[lift].append((reward, info.get("lift_failed_at")))
        finally:
            env.close()
    full, stopped = found["definition"], found["decided"]
    assert full == stopped and 0 < sum(r for r, _ in full) < len(full)
    assert all(0 < at <= 300 for reward, at in full if reward == 0 and at is not None)
    assert all(at == 0 for reward, at in full if reward == 1)


@pytest.mark.slow
def test_the_gymnasium_env_passes_the_checker_and_the_height_hack_has_three_actions():
    env = gym.make("taskrl/KukaGrasp-v0")
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, _ = env.reset(seed=0)
        assert obs["image"].shape == (64, 64, 3) and obs["image"].dtype == np.uint8
    finally:
        env.close()
    hack = KukaGraspEnv(height_hack=True)
    try:
        assert hack.action_space.shape == (3,)
        hack.reset(seed=0)
        steps, _, info = until_the_end(hack, np.zeros(3, dtype=np.float32))  # always down, whatever dz would say
        assert info["attempted"] and steps <= 4
    finally:
        hack.close()


@pytest.mark.slow
def test_the_random_policy_grasps_an_object_in_a_good_share_of_episodes():
    env = KukaGraspVectorEnv(KukaGraspSettings(vector_strategy="sync"), num_envs=2, seed=0)
    try:
        obs, ends, wins = env.reset(seed=0), 0, 0.0
        while ends < 16:
            obs, reward, terminated, truncated, info = env.step(env.scripted_action(obs))
            ends += int((terminated | truncated).sum())
            wins += float(reward.sum())
    finally:
        env.close()
    assert 0.15 <= wins / ends <= 0.7  # the benchmark's random policy: about 0.4


@pytest.mark.slow
def test_a_collection_run_stores_pictures_and_a_run_is_evaluated_on_the_test_objects(tmp_path, monkeypatch):
    from helpers import small_run
    from taskrl import loading

    run = small_run(
        "kukagrasp-random",
        tmp_path / "random",
        total_steps=30,
        num_envs=2,
        eval_episodes=1,
        image_size=32,
        vector_strategy="sync",
        hidden_sizes=(16,),
    )
    assert run.metrics["replay_transitions"] >= 6 and run.metrics["updates"] == 0
    built = []
    make = loading.make_env
    monkeypatch.setattr(
        loading, "make_env", lambda config, *a, **k: built.append(config.env_settings.objects) or make(config, *a, **k)
    )
    assert loading.evaluate_run(tmp_path / "random", episodes=1, held_out=True)["episodes"] == 1
    assert built == ["test"]


def test_the_protocol_takes_over_an_evaluation_only_for_the_same_weights_config_and_episode_count():
    """``benchmarks/kuka_grasp.py protocol --reuse``: an earlier row stands for a run only while what it evaluated is
    unchanged. Mutation: matching on the run's path alone (a run trained on, then re-scored from its old row) fails."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from kuka_grasp import reusable
    finally:
        sys.path.pop(0)
    same = {"config_sha256": "c0", "weights_sha256": "w0"}
    earlier = {
        "episodes": 100,
        "rows": [
            {"kind": "random (on the evaluation episodes)", "random_of": "runs/a", "config_sha256": "c0", "test": 0.4},
            {"run": "runs/a", **same, "test": 0.78},
            {"run": "runs/b", "config_sha256": "c1", "weights_sha256": "w1", "test": 0.71},
            {"run": "runs/c", "test": 0.5},  # raw data from before the digests: never taken over
        ],
    }
    now = {"runs/a": same, "runs/b": {"config_sha256": "c1", "weights_sha256": "trained on"}, "runs/c": same}
    kept, random_row = reusable(now, earlier, 100, "runs/a")
    assert set(kept) == {"runs/a"} and kept["runs/a"]["test"] == 0.78 and random_row["test"] == 0.4
    assert reusable(now, earlier, 50, "runs/a") == ({}, None)  # another episode count: other episodes
    now["runs/a"] = {"config_sha256": "changed", "weights_sha256": "w0"}
    assert reusable(now, earlier, 100, "runs/a") == ({}, None)
    assert reusable(now, None, 100, "runs/a") == ({}, None)


def test_the_protocol_pools_online_runs_apart_by_update_ratio_and_on_policy_window():
    """``benchmarks/kuka_grasp.py protocol``: an online run's kind names its update ratio and its on-policy window
    (``--recent-fraction``), so the pooled line never mixes runs trained differently. Mutation: leaving the window out
    of the kind pools the windowed runs with the uniform ones (the first assertion fails)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        from kuka_grasp import online_kind
    finally:
        sys.path.pop(0)
    uniform = {"updates_per_step": 0.25, "replay": {"recent_fraction": 0.0, "recent_episodes": 1000}}
    window = {"updates_per_step": 0.25, "replay": {"recent_fraction": 0.5, "recent_episodes": 1000}}
    assert online_kind("online", uniform) != online_kind("online", window)
    assert online_kind("online", uniform) == "online at 0.25 updates per env step"
    assert online_kind("online", window) == "online at 0.25 updates per env step, 50% of each batch from the 1,000 newest grasps"
    assert online_kind("online", {**uniform, "updates_per_step": 1.0}) != online_kind("online", uniform)
