import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from taskrl.agents.cem import CEMConfig, CrossEntropyMethod, action_bounds, maximize


def quadratic(optimum, scale=None):
    """score(a) = -sum_j scale_j (a_j - optimum_j)^2; its max over a box is clip(optimum)."""

    def score(actions):  # [B, N, A] -> [B, N]
        s = 1.0 if scale is None else scale.unsqueeze(1)
        return -(s * (actions - optimum.unsqueeze(1)).square()).sum(-1)

    return score


def test_finds_an_interior_maximum_in_one_dimension():
    g = torch.Generator().manual_seed(0)
    optimum = torch.tensor([[0.3]])
    a, s = maximize(quadratic(optimum), 1, torch.tensor([-1.0]), torch.tensor([1.0]), generator=g)
    assert a.shape == (1, 1) and s.shape == (1,)
    assert a.item() == pytest.approx(0.3, abs=0.03)
    assert s.item() == pytest.approx(-((a.item() - 0.3) ** 2), abs=1e-6)


def test_optimum_outside_the_box_gives_the_bound():
    g = torch.Generator().manual_seed(1)
    optimum = torch.tensor([[3.0, -5.0]])
    a, _ = maximize(quadratic(optimum), 1, torch.tensor([-1.0, -2.0]), torch.tensor([1.0, 2.0]), generator=g)
    assert a.tolist() == [[1.0, -2.0]]  # clipped samples land exactly on the bounds


def test_batched_states_each_get_their_own_optimum_in_several_dimensions():
    g = torch.Generator().manual_seed(2)
    b, dim = 64, 3
    low, high = torch.tensor([-1.0, 0.0, -2.0]), torch.tensor([1.0, 1.0, 2.0])
    optimum = low + (high - low) * torch.rand(b, dim, generator=g) * 1.2 - 0.1 * (high - low)  # some beyond the box
    scale = 0.5 + torch.rand(b, dim, generator=g)
    a, s = maximize(quadratic(optimum, scale), b, low, high, iterations=6, samples=128, elites=10, generator=g)
    best = torch.maximum(torch.minimum(optimum, high), low)
    assert (a - best).abs().max() < 0.08
    # the returned score is the score of the returned action
    torch.testing.assert_close(s, quadratic(optimum, scale)(a.unsqueeze(1)).squeeze(1))


def test_default_two_iterations_are_close_on_a_unit_box():
    g = torch.Generator().manual_seed(3)
    optimum = torch.rand(256, 2, generator=g) * 2 - 1
    a, _ = CrossEntropyMethod().maximize(quadratic(optimum), 256, -torch.ones(2), torch.ones(2), generator=g)
    assert (a - optimum).norm(dim=1).mean() < 0.1


def test_best_sample_is_returned_even_when_the_refit_moves_away():
    # Two optima; the refitted mean can land between them where the score is low. The result is
    # the best sample ever scored, so it never scores worse than the first round's best.
    g = torch.Generator().manual_seed(4)
    calls = []

    def score(actions):
        calls.append(actions.clone())
        return torch.maximum(-(actions - 0.8).square(), -(actions + 0.8).square()).sum(-1)

    a, s = maximize(score, 32, torch.tensor([-1.0]), torch.tensor([1.0]), iterations=3, generator=g)
    first_best = score(calls[0]).max(dim=1).values
    assert (s >= first_best).all()
    assert ((a.abs() - 0.8).abs() < 0.1).all()


def test_score_fn_is_called_once_per_iteration_with_all_samples():
    shapes = []

    def score(actions):
        shapes.append(tuple(actions.shape))
        return -actions.square().sum(-1)

    maximize(score, 5, -torch.ones(3), torch.ones(3), iterations=3, samples=(16, 32, 32), elites=4)
    assert shapes == [(5, 16, 3), (5, 32, 3), (5, 32, 3)]
    shapes.clear()
    CrossEntropyMethod(CEMConfig(first_samples=8)).maximize(score, 5, -torch.ones(3), torch.ones(3))
    assert shapes == [(5, 8, 3), (5, 64, 3)]


def test_warm_start_searches_near_the_given_mean_with_fewer_rounds():
    shapes, seen = [], []

    def score(actions):
        shapes.append(tuple(actions.shape))
        seen.append(actions)
        return -(actions - 0.5).square().sum(-1)

    cem = CrossEntropyMethod(CEMConfig(warm_std=0.05, warm_iterations=1))
    g = torch.Generator().manual_seed(5)
    a, _ = cem.maximize(score, 4, -torch.ones(2), torch.ones(2), init_mean=torch.full((4, 2), 0.45), generator=g)
    assert shapes == [(4, 64, 2)]
    assert (seen[0] - 0.45).abs().max() < 0.05 * 5  # all samples within 5 sigma of the warm start
    assert (a - 0.5).abs().max() < 0.05


def test_a_configured_initial_mean_starts_every_cold_search_there():
    """``init_mean`` in half-widths from the centre: (0.5, -1) on the box [0, 2] x [-3, 1] is (1.5, -3). Mutation:
    the configured mean ignored (the search starting at the centre) fails."""
    seen = []

    def score(actions):
        seen.append(actions)
        return torch.zeros(actions.shape[:2])

    cem = CrossEntropyMethod(CEMConfig(iterations=1, samples=32, elites=4, init_std=0.02, init_mean=(0.5, -1.0), truncate=True))
    cem.maximize(score, 3, torch.tensor([0.0, -3.0]), torch.tensor([2.0, 1.0]), generator=torch.Generator().manual_seed(0))
    assert (seen[0][..., 0] - 1.5).abs().max() < 0.2
    assert (seen[0][..., 1] + 3.0).abs().max() < 0.3 and (seen[0][..., 1] >= -3.0).all()
    # a warm start still wins over the configured prior
    seen.clear()
    g = torch.Generator().manual_seed(1)
    cem.maximize(score, 3, torch.tensor([0.0, -3.0]), torch.tensor([2.0, 1.0]), init_mean=torch.tensor([0.2, 0.5]), generator=g)
    assert (seen[0][..., 1] - 0.5).abs().max() < 1.0  # 5 sigma of the warm start's 0.1 half-width
    with pytest.raises(ValueError, match="init_mean"):
        cem.maximize(score, 3, -torch.ones(3), torch.ones(3))


def test_an_initial_mean_outside_the_box_is_refused():
    from taskrl.errors import ConfigError

    with pytest.raises(ConfigError, match="init_mean"):
        CEMConfig(init_mean=(0.0, -1.5)).validate()


def test_return_distribution_gives_the_refit_mean_and_std():
    g = torch.Generator().manual_seed(6)
    a, s, mean, std = maximize(
        quadratic(torch.zeros(3, 2)), 3, -torch.ones(2), torch.ones(2), generator=g, return_distribution=True
    )
    assert mean.shape == std.shape == (3, 2)
    assert (std >= 0).all() and (mean.abs() < 0.5).all()


@settings(max_examples=40, deadline=None)
@given(
    dim=st.integers(1, 4),
    batch=st.integers(1, 6),
    lows=st.lists(st.floats(-5.0, 5.0), min_size=4, max_size=4),
    widths=st.lists(st.floats(1e-3, 10.0), min_size=4, max_size=4),
    mean_offset=st.floats(-100.0, 100.0),
    std=st.floats(0.0, 1e3),
    iterations=st.integers(1, 3),
    seed=st.integers(0, 2**31 - 1),
)
def test_actions_never_leave_the_box(dim, batch, lows, widths, mean_offset, std, iterations, seed):
    low = torch.tensor(lows[:dim])
    high = low + torch.tensor(widths[:dim])
    g = torch.Generator().manual_seed(seed)
    seen = []

    def score(actions):
        seen.append(actions)
        return torch.randn(actions.shape[:2], generator=g)

    a, _ = maximize(
        score,
        batch,
        low,
        high,
        iterations=iterations,
        samples=8,
        elites=3,
        init_mean=low + mean_offset,
        init_std=std,
        generator=g,
    )
    for actions in seen + [a.unsqueeze(1)]:
        assert ((actions >= low) & (actions <= high)).all()


def test_action_bounds_accepts_a_box_or_a_pair_and_rejects_bad_bounds():
    class Box:  # duck-typed like gymnasium.spaces.Box
        low, high = np.array([-1.0, 0.0], dtype=np.float32), np.array([1.0, 2.0], dtype=np.float32)

    low, high = action_bounds(Box())
    assert low.tolist() == [-1.0, 0.0] and high.tolist() == [1.0, 2.0]
    low, high = action_bounds((torch.tensor([-2.0]), [3.0]))
    assert low.tolist() == [-2.0] and high.tolist() == [3.0]
    with pytest.raises(ValueError, match="finite"):
        action_bounds((np.array([-np.inf]), np.array([1.0])))
    with pytest.raises(ValueError, match="low < high"):
        action_bounds(([1.0], [1.0]))
    with pytest.raises(ValueError, match="Box"):
        action_bounds(3)


def test_truncated_sampling_puts_no_mass_on_the_bounds_and_matches_the_truncated_normal():
    from taskrl.agents.cem import sample_in_box

    g = torch.Generator().manual_seed(0)
    mean, std = torch.full((1, 3), 0.5), torch.ones(1, 3)
    low, high = -torch.ones(3), torch.ones(3)
    clipped = sample_in_box(mean, std, 20_000, low, high, "clip", g)
    truncated = sample_in_box(mean, std, 20_000, low, high, "truncated", g)
    assert (clipped == 1.0).float().mean() > 0.25  # P(N(0.5, 1) > 1) = 0.31 lands on the bound
    assert (truncated.abs() > 0.999).float().mean() < 0.002
    assert ((truncated >= low) & (truncated <= high)).all()
    # mean of N(0.5, 1) truncated to [-1, 1]: mu + (phi(alpha) - phi(beta)) / (Phi(beta) - Phi(alpha)) * sigma
    normal = torch.distributions.Normal(0.0, 1.0)
    alpha, beta = torch.tensor(-1.5), torch.tensor(0.5)
    pdf = lambda z: normal.log_prob(z).exp()  # noqa: E731
    expected = 0.5 + (pdf(alpha) - pdf(beta)) / (normal.cdf(beta) - normal.cdf(alpha))
    assert truncated.mean().item() == pytest.approx(expected.item(), abs=0.01)


def test_truncated_cem_still_finds_interior_and_boundary_optima():
    cem = CrossEntropyMethod(CEMConfig(iterations=4, samples=128, elites=8, truncate=True))
    optimum = torch.tensor([[0.3, -0.2], [2.0, -3.0]])  # the second is outside the box: its max is at the corner
    a, _ = cem.maximize(quadratic(optimum), 2, -torch.ones(2), torch.ones(2), generator=torch.Generator().manual_seed(0))
    assert a[0].tolist() == pytest.approx([0.3, -0.2], abs=0.05)
    assert a[1].tolist() == pytest.approx([1.0, -1.0], abs=0.05)
