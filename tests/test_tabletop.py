"""The pixel tabletop (tasks as verb-colour sentences, scripted experts) and behaviour cloning from its pictures."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from helpers import small_run
from taskrl.agents.bc import BCAgent, BCConfig
from taskrl.agents.spec import AgentInputs
from taskrl.conditioning.networks import ConditioningConfig, TaskConditioning
from taskrl.conditioning.task_encoders import OneHotTaskEncoder
from taskrl.demos.collect import collect_demos
from taskrl.demos.dataset import read_demonstrations
from taskrl.encoders import FiLMPictureEncoder
from taskrl.envs.tabletop import COLOURS, HELD_OUT, PUSHER_COLOUR, TABLETOP_TASKS, Tabletop


def _centre(picture: torch.Tensor, colour) -> torch.Tensor:
    """``[B, 2]`` (x, y) of the pixels of ``colour`` in ``[B, S, S, 3]`` pictures."""
    size = picture.shape[1]
    hit = (picture.float() - torch.tensor(colour, dtype=torch.float32)).abs().sum(-1) < 30  # [B, S, S]
    centres = (torch.arange(size, dtype=torch.float32) + 0.5) / size * 2 - 1
    weight = hit.float().sum((1, 2))
    x = (hit.float() * centres.view(1, 1, -1)).sum((1, 2)) / weight
    y = -(hit.float() * centres.view(1, -1, 1)).sum((1, 2)) / weight
    return torch.stack([x, y], 1)


def _success_per_task(env: Tabletop, policy, seed: int) -> torch.Tensor:
    """``[K]`` the share of each task's copies whose first episode under ``policy`` succeeded."""
    obs = env.reset(seed=seed)
    done = torch.zeros(env.num_envs, dtype=torch.bool)
    success = torch.zeros_like(done)
    for _ in range(env.horizon):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        success |= info["is_success"].bool() & ~done
        done |= terminated | truncated
    return torch.stack([success[env.slot_tasks == k].float().mean() for k in range(len(env.task_set))])


def test_the_camera_shows_every_block_and_the_pusher_where_they_are():
    env = Tabletop(num_envs=16, image_size=64, seed=0)
    obs = env.reset(seed=0)
    assert env.single_observation_space.contains({k: v[0].numpy() for k, v in obs.items()})
    for k, colour in enumerate(COLOURS.values()):
        assert torch.allclose(_centre(obs["image"], colour), env.blocks[:, k], atol=0.03)
    assert torch.allclose(_centre(obs["image"], PUSHER_COLOUR), obs["observation"], atol=0.03)


def test_the_pusher_shoves_the_block_it_runs_into():
    env = Tabletop(num_envs=1, tasks=["push-left-red"], seed=0)
    env.reset(seed=0)
    env.blocks[0] = torch.tensor([[0.0, 0.0], [0.0, 0.7], [0.0, -0.7]])
    env.pusher[0] = torch.tensor([0.3, 0.0])
    for _ in range(3):
        env.step(torch.tensor([[-1.0, 0.0]]))
    assert env.blocks[0, 0, 0] < -0.05 and abs(float(env.blocks[0, 0, 1])) < 1e-5  # pushed left along the line
    assert torch.allclose(env.blocks[0, 1:], torch.tensor([[0.0, 0.7], [0.0, -0.7]]))  # the others untouched


def test_every_scripted_expert_succeeds_and_a_random_policy_rarely_does():
    env = Tabletop(num_envs=9 * 20, task_sampling="fixed", seed=1)
    outcome = {}
    for name, policy in (("expert", env.expert), ("random", lambda obs: torch.rand(env.num_envs, 2) * 2 - 1)):
        outcome[name] = _success_per_task(env, policy, seed=1)
    assert (outcome["expert"] >= 0.95).all()
    assert outcome["random"].mean() < 0.15


def test_tabletop_passes_gymnasiums_env_checker_and_a_task_can_be_chosen():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("taskrl/Tabletop-v0", render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    obs, _ = env.reset(seed=0, options={"task": "push-left-blue"})
    assert obs["task"] == [n for n, _ in TABLETOP_TASKS].index("push-left-blue") and obs["image"].shape == (32, 32, 3)
    assert env.render().shape == (128, 128, 3)


def test_the_held_out_combinations_leave_every_verb_and_colour_in_training():
    training = [n for n, _ in TABLETOP_TASKS if n not in HELD_OUT]
    assert len(HELD_OUT) == 3 and len(training) == 6
    for word in ("reach", "push-left", "push-right", *COLOURS):
        assert any(word in n for n in training) and sum(word in n for n in HELD_OUT) >= 1


@pytest.fixture(scope="module")
def reach_demos(tmp_path_factory):
    out = tmp_path_factory.mktemp("demos") / "tabletop"
    collect_demos("tabletop:reach-red,reach-blue", 30, out, seed=3)
    return out


def test_collected_demonstrations_keep_the_pictures_of_their_states(reach_demos):
    demos = read_demonstrations(reach_demos)
    assert demos.images is not None and demos.images.dtype == torch.uint8
    assert demos.images.shape == (demos.num_steps, 32, 32, 3)
    # where the picture shows the pusher is the state's pusher: the centroid of whiteness (the darkest channel of
    # the table, the blocks and their anti-aliased edges stays under 120; the pusher's is 240)
    white = ((demos.images.float().min(-1).values - 120) / (240 - 120)).clamp(0, 1)
    centres = (torch.arange(32, dtype=torch.float32) + 0.5) / 16 - 1
    total = white.sum((1, 2))
    pusher = torch.stack(
        [(white * centres.view(1, 1, -1)).sum((1, 2)) / total, -(white * centres.view(1, -1, 1)).sum((1, 2)) / total], 1
    )
    assert (pusher - demos.observations).abs().max() < 0.04  # under a pixel (0.0625)
    kept = demos.select_tasks(["reach-blue"])
    assert kept.images.shape[0] == kept.num_steps < demos.num_steps


def _pixel_agent(picture_shift: int | None = None, **settings) -> BCAgent:
    conditioning = TaskConditioning(OneHotTaskEncoder(2), ConditioningConfig(architecture="film"))
    box = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    inputs = AgentInputs(("observation", "image"), 2 + 32 * 32 * 3, box, (32, 32, 3), picture_shift)
    config = BCConfig(hidden_sizes=(64, 64), embedding_noise=0.0, lr=1e-3, **settings)
    return BCAgent(inputs, config, "cpu", conditioning)


def test_the_picture_encoder_is_modulated_by_the_task_in_every_block():
    """Each FiLM layer, perturbed alone, changes the features. Mutation: FiLM applied in block 0 only (the per-block
    loop of ``FiLMPictureEncoder._trunk``) leaves the others' perturbations without effect and fails."""
    torch.manual_seed(0)
    encoder = FiLMPictureEncoder((32, 32, 3), "conv", 16, context_dim=2)
    pictures = torch.randint(0, 255, (4, 32, 32, 3), dtype=torch.uint8)
    one, other = torch.tensor([[1.0, 0.0]]).expand(4, 2), torch.tensor([[0.0, 1.0]]).expand(4, 2)
    assert torch.allclose(encoder(pictures, one), encoder(pictures, other))  # FiLM starts as the identity
    assert len(encoder.films) == len(encoder.blocks) == 4
    for i, film in enumerate(encoder.films):
        for each in encoder.films:
            torch.nn.init.zeros_(each.generator.weight)
        torch.nn.init.normal_(film.generator.weight, std=0.5)
        assert not torch.allclose(encoder(pictures, one), encoder(pictures, other), atol=1e-3), f"FiLM {i} has no effect"


def test_every_pixel_bc_update_shifts_the_pictures(monkeypatch, reach_demos):
    """The encoder is handed the shifted pictures (or, with no pad, the stored ones). Mutation: BC computes the
    shifted pictures, then trains on the unshifted ones (``bc.py``'s update) fails."""
    import taskrl.agents.bc as bc

    shifted = []
    shift = bc.shift_pictures
    monkeypatch.setattr(
        bc,
        "shift_pictures",
        lambda obs, pad, generator=None, coordinates=(): shifted.append(shift(obs, pad, generator, coordinates)) or shifted[-1],
    )
    demos = read_demonstrations(reach_demos)
    for pad in (2, 0):
        shifted.clear()
        agent = _pixel_agent(picture_shift=pad)
        received = []
        agent.encoder.register_forward_hook(lambda module, args, out, received=received: received.append(args[0]))
        batch = agent.use_dataset(demos).sample(8, torch.Generator().manual_seed(0))
        agent.update(batch)
        assert len(received) == 1
        got = received[0].reshape(batch.obs["image"].shape)
        if pad:
            assert len(shifted) == 1 and torch.equal(got, shifted[0]["image"].to(got.dtype))
            assert not torch.equal(got, batch.obs["image"].to(got.dtype))  # moved: 8 pictures at random offsets
        else:
            assert shifted == [] and torch.equal(got, batch.obs["image"].to(got.dtype))


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_bc_from_pictures_reaches_the_block_its_task_names(reach_demos):
    """Where the named block is shows only in the picture, and which block only in the task: uniformly random
    actions touch it in 12.5% of 1,000 episodes; cloned from 30 demonstrations per task, in most."""
    torch.manual_seed(0)
    demos = read_demonstrations(reach_demos)
    agent = _pixel_agent()
    sampler = agent.use_dataset(demos)
    g = torch.Generator().manual_seed(0)
    for _ in range(400):
        agent.update(sampler.sample(64, g))
    env = Tabletop(num_envs=2 * 25, tasks=["reach-red", "reach-blue"], task_sampling="fixed", seed=7)
    per_task = _success_per_task(env, agent.act, seed=7).tolist()
    assert min(per_task) >= 0.7, per_task


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_pixel_bc_preset_trains_and_reloads_from_the_cli(tmp_path):
    out = tmp_path / "demos"
    collect_demos("tabletop", 2, out, seed=3)
    run = small_run("bc-tabletop-language", tmp_path / "run", dataset=str(out), total_steps=20, eval_interval=20, eval_episodes=1)
    assert run.metrics["updates"] == 20 and 0.0 <= run.metrics["success_rate"] <= 1.0
    import taskrl

    again = taskrl.evaluate_run(tmp_path / "run", episodes=1)
    assert set(again["tasks"]) == {n for n, _ in TABLETOP_TASKS if n not in HELD_OUT}
    from taskrl.prompting import evaluate_prompted

    held = evaluate_prompted(tmp_path / "run", episodes=1)
    assert set(held["tasks"]) == set(HELD_OUT)


def test_pictures_of_another_size_than_the_runs_are_refused_in_one_line(reach_demos):
    from taskrl.errors import ConfigError

    conditioning = TaskConditioning(OneHotTaskEncoder(2), ConditioningConfig(architecture="film"))
    inputs = AgentInputs(("observation", "image"), 2 + 16 * 16 * 3, gym.spaces.Box(-1.0, 1.0, (2,), np.float32), (16, 16, 3))
    agent = BCAgent(inputs, BCConfig(hidden_sizes=(8,)), "cpu", conditioning)
    with pytest.raises(ConfigError, match="--image-size 32"):
        agent.use_dataset(read_demonstrations(reach_demos))


def test_the_video_env_numbers_the_tasks_as_the_run_does():
    from taskrl.envs.registry import env_family
    from taskrl.envs.tabletop import TabletopSettings

    settings = TabletopSettings()
    video = env_family("tabletop").video_env(settings)
    assert video.unwrapped.task_set.names == settings.names() == [n for n, _ in TABLETOP_TASKS if n not in HELD_OUT]
    video.close()
