"""Images through the stack: the encoders, DrQ's random shift, the flat input, QT-Opt from pixels."""

from __future__ import annotations

import pytest
import torch

from taskrl.agents.parts import ObservationInput
from taskrl.agents.qtopt import QTOptAgent, QTOptConfig
from taskrl.encoders import ImageStateInput, random_shift
from taskrl.envs.grasp import Grasp, GraspSettings
from taskrl.nets import StateActionQ
from taskrl.replay.batch import Batch


def one_step(env: Grasp, obs: dict, action: torch.Tensor) -> Batch:
    """The batch of one step of every copy of ``env`` from ``obs``."""
    _, reward, terminated, truncated, info = env.step(action)
    index = torch.zeros(env.num_envs, dtype=torch.long)
    return Batch(obs, action, reward, info["final_obs"], terminated, truncated, index, index)


def test_random_shift_moves_each_picture_by_its_own_offset_within_the_pad():
    images = torch.zeros(64, 12, 12, 3, dtype=torch.uint8)
    images[:, 6, 5] = 255  # one bright pixel, away from the border
    shifted = random_shift(images, 2, torch.Generator().manual_seed(0))
    assert shifted.shape == images.shape and shifted.dtype == torch.uint8
    where = (shifted[..., 0] == 255).nonzero()[:, 1:]  # [64, (row, col)]: exactly one bright pixel each
    assert where.shape == (64, 2)
    moves = where - torch.tensor([6, 5])
    assert moves.abs().max() <= 2 and len({tuple(m) for m in moves.tolist()}) > 10
    assert torch.equal(random_shift(images, 0), images)


def test_image_columns_pass_unnormalised_and_the_vector_is_normalised():
    inputs = ObservationInput(("observation", "image"), 3 + 2 * 2 * 3, normalize=True, raw_dim=12)
    obs = {"observation": torch.randn(32, 3) * 10 + 5, "image": torch.randint(0, 256, (32, 2, 2, 3), dtype=torch.uint8)}
    inputs.update_statistics(obs)
    x = inputs(obs)
    assert torch.equal(x[:, 3:], obs["image"].flatten(1).float())
    assert x[:, :3].mean().abs() < 0.5 and x[:, :3].std() < 2


def test_cem_scores_encode_each_picture_once_and_match_the_plain_forward_pass():
    torch.manual_seed(0)
    encoder = ImageStateInput(2, (16, 16, 3), "conv", 8)
    q = StateActionQ(2 + 16 * 16 * 3, 4, (32,), encoder)
    calls = []
    encoder.register_forward_hook(lambda module, args, out: calls.append(args[0].shape[0]))
    x = torch.cat([torch.randn(5, 2), torch.randint(0, 256, (5, 768)).float()], 1)
    actions = torch.rand(5, 7, 4) * 2 - 1
    with torch.no_grad():
        scores = q.score_actions(x, actions)
        assert calls == [5]  # one encoding per state, not per scored action
        plain = q(x.repeat_interleave(7, 0), actions.reshape(35, 4)).view(5, 7)
    torch.testing.assert_close(scores, plain, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("encoder", ["conv", "resnet"])
def test_qtopt_from_pixels_trains_its_encoder_and_each_target_has_its_own(encoder):
    env = Grasp(GraspSettings(image_size=16), num_envs=8, seed=0)
    obs = env.reset(seed=0)
    space = env.single_observation_space
    dim = 5 + 16 * 16 * 3
    agent = QTOptAgent(
        ("observation", "image"),
        dim,
        env.single_action_space,
        QTOptConfig(hidden_sizes=(32,), encoder=encoder),
        image_shape=(16, 16, 3),
    )
    assert space["image"].shape == (16, 16, 3)
    g = torch.Generator().manual_seed(0)
    batch = one_step(env, obs, agent.act(obs, explore=True, generator=g))
    before = [p.clone() for p in agent.q.state_input.parameters()]
    agent.update(batch, generator=g)
    assert all(not torch.equal(a, b) for a, b in zip(agent.q.state_input.parameters(), before))
    assert agent.q_target1.state_input is not agent.q.state_input and agent.q_target2.state_input is not agent.q.state_input


def test_every_update_shifts_the_pictures_of_both_states_unless_turned_off(monkeypatch):
    import taskrl.agents.qtopt as qtopt

    seen = []
    monkeypatch.setattr(qtopt, "random_shift", lambda images, pad, generator: seen.append(pad) or images)
    env = Grasp(GraspSettings(image_size=16), num_envs=4, seed=0)
    batch = one_step(env, env.reset(seed=0), torch.zeros(4, 4))
    for pad, expected in ((4, [4, 4]), (0, [])):
        seen.clear()
        config = QTOptConfig(hidden_sizes=(8,), augment_pad=pad)
        QTOptAgent(("observation", "image"), 5 + 768, env.single_action_space, config, image_shape=(16, 16, 3)).update(batch)
        assert seen == expected
