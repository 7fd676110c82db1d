"""Hand-made batches shared by the agent tests: two one-hot states, explicit keys."""

import torch
import torch.nn.functional as F

from taskrl.replay.batch import Batch


def onehot_batch(reward, terminated, truncated, next_state, action=None) -> Batch:
    """Transitions into one-hot states ``next_state`` (s = s'), with the given flags."""
    n = len(reward)
    onehot = F.one_hot(torch.tensor(next_state), 2).float()
    return Batch(
        obs={"observation": onehot},
        action=torch.zeros(n, 1) if action is None else action,
        reward=torch.tensor(reward),
        next_obs={"observation": onehot},
        terminated=torch.tensor(terminated),
        truncated=torch.tensor(truncated),
        episode=torch.zeros(n, dtype=torch.long),
        step=torch.zeros(n, dtype=torch.long),
    )


def bandit_batch(best: torch.Tensor, generator: torch.Generator, reward=lambda gap: -4.0 * gap.square(), n: int = 128) -> Batch:
    """One round of a one-step continuous bandit: random state s in {0, 1}, uniform action a in
    [-1, 1], reward a function of ``a - best[s]``; every transition terminates."""
    s = torch.randint(0, 2, (n,), generator=generator)
    a = torch.rand(n, 1, generator=generator) * 2 - 1
    done = torch.ones(n, dtype=torch.bool)
    onehot = F.one_hot(s, 2).float()
    return Batch(
        obs={"observation": onehot},
        action=a,
        reward=reward(a[:, 0] - best[s]),
        next_obs={"observation": onehot},
        terminated=done,
        truncated=~done,
        episode=s,
        step=s,
    )
