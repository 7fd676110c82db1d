import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from taskrl.normalization import RunningNorm


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 50), min_size=1, max_size=6), st.integers(0, 2**31))
def test_running_moments_equal_the_moments_of_all_data(batch_sizes, seed):
    g = torch.Generator().manual_seed(seed)
    batches = [torch.randn(n, 3, generator=g, dtype=torch.float64).float() * 3 + 1 for n in batch_sizes]
    norm = RunningNorm(3)
    for b in batches:
        norm.update(b)
    data = torch.cat(batches)
    torch.testing.assert_close(norm.mean, data.mean(0), atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(norm.var, data.var(0, unbiased=False), atol=1e-4, rtol=1e-4)
    assert int(norm.count) == data.shape[0]


def test_normalised_values_are_standardised_and_clipped():
    norm = RunningNorm(2, clip=5.0)
    x = torch.tensor([[0.0, 7.0], [1.0, 7.0]] * 50)
    norm.update(x)
    out = norm(x)
    torch.testing.assert_close(out[:, 0].abs(), torch.ones(100))  # bits {0, 1} become -1 / +1
    assert torch.equal(out[:, 1], torch.zeros(100))  # constant input: std floored by eps, stays finite
    assert norm(torch.tensor([[1000.0, 7.0]]))[0, 0] == 5.0
