"""The shared agent parts against their reference formulas."""

import pytest
import torch

from taskrl.agents.parts import linear_schedule, negative_return_bounds, polyak_update, td_target


@pytest.mark.parametrize("tau", [0.005, 0.3, 1.0])
def test_the_fused_polyak_update_is_the_reference_formula(tau):
    g = torch.Generator().manual_seed(0)
    online = [torch.randn(4, 3, generator=g), torch.randn(7, generator=g)]
    target = [torch.randn(4, 3, generator=g), torch.randn(7, generator=g)]
    expected = [tau * p + (1 - tau) * t for p, t in zip(online, target)]  # theta' <- tau theta + (1 - tau) theta'
    polyak_update(target, online, tau)
    for got, want in zip(target, expected):
        torch.testing.assert_close(got, want)


def test_the_td_target_bootstraps_through_truncation_but_not_termination():
    reward = torch.tensor([-1.0, -1.0, 0.0])
    terminated = torch.tensor([False, True, False])
    next_value = torch.tensor([-5.0, -5.0, -80.0])
    y = td_target(reward, terminated, next_value, gamma=0.9)
    torch.testing.assert_close(y, torch.tensor([-1.0 - 4.5, -1.0, -72.0]))
    low, high = negative_return_bounds(0.9)
    clipped = td_target(reward, terminated, next_value, gamma=0.9, clip=(low, high))
    assert (low, high) == (pytest.approx(-10.0), 0.0) and clipped[2].item() == pytest.approx(-10.0)


def test_the_linear_schedule():
    assert linear_schedule(0.5, 0.1, 100, 0) == 0.5
    assert linear_schedule(0.5, 0.1, 100, 50) == pytest.approx(0.3)
    assert linear_schedule(0.5, 0.1, 100, 10_000) == pytest.approx(0.1)
    assert linear_schedule(0.5, 0.1, 0, 0) == 0.1  # no decay: the end value throughout


def test_truncated_exploration_noise_stays_off_the_bounds_and_clipped_noise_piles_on_them():
    from taskrl.agents.parts import explore_in_box

    near = torch.full((20_000, 2), 0.9)  # CEM actions near the upper bound
    g = torch.Generator().manual_seed(0)
    clipped = explore_in_box(near, 0.2, 0.0, g)
    truncated = explore_in_box(near, 0.2, 0.0, g, truncated=True)
    assert (clipped == 1.0).float().mean() > 0.25  # P(N(0.9, 0.2) > 1) = 0.31
    assert (truncated.abs() >= 1.0 - 1e-6).float().mean() < 0.001 and (truncated <= 1.0).all()
    assert abs(truncated.mean().item() - 0.798) < 0.01  # the mean of N(0.9, 0.2) truncated to [-1, 1]
