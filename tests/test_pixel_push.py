"""PixelPush: a block pushed to a goal shown as a picture (the goal-image task with an object to move)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import taskrl
from helpers import small_run
from taskrl.envs.pixel_push import PixelPush
from taskrl.envs.tabletop import BLOCK, COLOURS, PUSHER, PUSHER_COLOUR, TABLE


def red_centre(picture: torch.Tensor) -> torch.Tensor:
    """``[B, 2]``: the centre (table units, y up) of the red block in ``[B, size, size, 3]`` pictures."""
    size = picture.shape[1]
    red = ((picture[..., 0].float() - TABLE[0]) / (COLOURS["red"][0] - TABLE[0])).clamp(0, 1)
    red = red * (picture[..., 1].float() < 100)  # not the white pusher
    centres = (torch.arange(size, dtype=torch.float32) + 0.5) / size * 2 - 1
    weight = red.sum((1, 2))
    x = (red * centres.view(1, 1, -1)).sum((1, 2)) / weight
    y = (red * -centres.view(1, -1, 1)).sum((1, 2)) / weight
    return torch.stack([x, y], 1)


def expert(env: PixelPush) -> torch.Tensor:
    """Goes round to the side of the block away from its goal (beside it, then behind it) and pushes it there."""
    block, goal, pusher = env.block, env.goal, env.position
    to_goal = goal - block
    distance = torch.linalg.vector_norm(to_goal, dim=-1, keepdim=True).clamp(min=1e-6)
    d = to_goal / distance
    perp = torch.stack([-d[:, 1], d[:, 0]], 1)
    along, across = ((pusher - block) * d).sum(-1), ((pusher - block) * perp).sum(-1)
    contact = PUSHER + BLOCK
    side = torch.where(across >= 0, 1.0, -1.0)[:, None]
    behind = block - d * (contact + 0.01)
    corner = block + perp * side * (contact + 0.05) - d * (contact + 0.06)
    beside = block + perp * side * (contact + 0.06) + d * along[:, None]
    waypoint = torch.where((across.abs() > contact + 0.02)[:, None], corner, beside)
    waypoint = torch.where((along < -contact)[:, None], behind, waypoint)  # behind the block: never touches it
    push = d * (distance / 0.1).clamp(max=1.0) - perp * across[:, None] * 5.0
    pushing = (along < -contact + 0.02) & (across.abs() < 0.04)
    action = torch.where(pushing[:, None], push, (waypoint - pusher) / 0.1)
    action = torch.where(distance < 0.04, 0.0, action)  # there: stay (near the goal its direction swings)
    return action / action.abs().amax(1, keepdim=True).clamp(min=1.0)  # scaled into the box, its direction kept


def test_the_pictures_show_the_block_now_and_at_its_goal_and_the_state_goals_say_where():
    env = PixelPush(num_envs=64, seed=0)
    obs = env.reset(seed=0)
    assert env.single_observation_space.contains({k: v[0].numpy() for k, v in obs.items()})
    assert torch.equal(obs["achieved_goal"], env.block) and torch.equal(obs["desired_goal"], env.goal)
    assert torch.equal(obs["observation"], env.position)  # the pusher's own position; the block is only pictured
    # the pusher may hide part of the block in the scene; the goal picture shows the block alone
    assert torch.allclose(red_centre(obs["goal_image"]), obs["desired_goal"], atol=0.02)
    visible = torch.linalg.vector_norm(env.position - env.block, dim=-1) > PUSHER + BLOCK * 1.5
    assert visible.sum() > 40 and torch.allclose(red_centre(obs["image"])[visible], env.block[visible], atol=0.02)
    state = PixelPush(num_envs=2, seed=0, observation="state").reset(seed=0)
    assert set(state) == {"observation", "achieved_goal", "desired_goal"} and state["observation"].shape == (2, 4)


def test_the_pusher_pushes_the_block_to_its_goal_and_random_actions_rarely_do():
    env = PixelPush(num_envs=256, seed=1, horizon=50)
    env.reset(seed=1)
    start = env.block.clone()
    ended = torch.zeros(256, dtype=torch.bool)
    for _ in range(50):
        _, reward, terminated, truncated, info = env.step(expert(env))
        ended = ended | truncated | terminated
        if ended.all():
            break
    final = info["final_obs"]
    solved = torch.linalg.vector_norm(final["achieved_goal"] - final["desired_goal"], dim=-1) <= env.distance_threshold
    assert solved.float().mean() >= 0.95 and torch.equal(reward == 0, solved)  # sparse: 0 at the goal, else -1
    assert (torch.linalg.vector_norm(final["achieved_goal"] - start, dim=-1) > 0.15).float().mean() > 0.9  # it moved
    env = PixelPush(num_envs=256, seed=2, horizon=50)
    env.reset(seed=2)
    hit = torch.zeros(256, dtype=torch.bool)
    for _ in range(50):
        _, reward, *_ = env.step(torch.rand(256, 2) * 2 - 1)
        hit |= reward == 0
    assert hit.float().mean() < 0.05  # at any step, not only the last


@pytest.mark.parametrize("observation", ["pixels", "state"])
def test_pixelpush_passes_gymnasiums_env_checker(observation):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("taskrl/PixelPush-v0", observation=observation, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (128, 256, 3)  # the scene and the goal picture side by side, 4x
    if observation == "pixels":
        assert np.array_equal(frame[::4, :128:4], obs["image"]) and np.array_equal(frame[::4, 128::4], obs["goal_image"])


def _shows_the_pusher(pictures: torch.Tensor) -> torch.Tensor:
    """``[B]``: whether a picture has a pixel of the pusher's colour."""
    return (pictures == torch.tensor(PUSHER_COLOUR, dtype=torch.uint8)).all(-1).flatten(1).any(1)


def test_hindsight_gives_the_picture_of_the_state_where_the_block_was():
    """Relabelled goal pictures show the block where it was, alone, as the env's own goal pictures do (one
    distribution). Mutation: relabelling with the reached moment's picture (the pusher beside the block) fails."""
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.run import build
    from taskrl.training.offpolicy import batch_sampler

    config = with_overrides(preset_config("pixelpush-sac-her"), {"num_envs": 8, "her_k": 1000, "threads": 1})
    parts = build(config)
    try:
        env, replay, g = parts.env, parts.replay, torch.Generator().manual_seed(0)
        obs = env.reset(seed=0)
        replay.start(obs)
        for _ in range(60):
            action = 0.7 * expert(env) + 0.6 * (torch.rand(8, 2, generator=g) * 2 - 1)  # moves the blocks, not always well
            next_obs, reward, terminated, truncated, info = env.step(action)
            replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
        batch = batch_sampler(parts.sampler, 512, g)()
        relabelled = torch.linalg.vector_norm(batch.obs["desired_goal"] - batch.obs["achieved_goal"], dim=-1) > 0
        # a relabelled goal is a block position of the episode, and its picture shows the block there
        assert torch.allclose(red_centre(batch.obs["goal_image"]), batch.obs["desired_goal"], atol=0.03)
        assert torch.equal(batch.next_obs["goal_image"], batch.obs["goal_image"]) and relabelled.float().mean() > 0.5
        assert not _shows_the_pusher(batch.obs["goal_image"]).any() and _shows_the_pusher(batch.obs["image"]).all()
        solved = (batch.reward == 0).float().mean()
        assert 0.05 < solved < 0.95  # relabelled goals are often reached, the commanded ones mostly not
        assert torch.equal(batch.reward == 0, env.compute_reward(batch.next_obs["achieved_goal"], batch.obs["desired_goal"]) == 0)
        assert parts.agent.inputs.keys == ("observation", "image", "goal_image")  # the state goal is never read
    finally:
        parts.close()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("preset", ["pixelpush-sac-her", "pixelpush-state-sac-her"])
def test_the_presets_train_save_load_and_act(tmp_path, preset):
    small_run(preset, tmp_path / "run", total_steps=1200, learning_starts=800, eval_interval=1200, batch_size=32, threads=1)
    loaded = taskrl.load(tmp_path / "run")
    env = PixelPush(num_envs=1, seed=3, observation="state" if "state" in preset else "pixels")
    obs = env.reset(seed=3)
    assert loaded.act({k: v for k, v in obs.items() if k not in ("achieved_goal",)}).shape == (1, 2)
