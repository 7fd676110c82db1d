"""Deterministic evaluation on a batched environment: one episode per copy, all in parallel."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from taskrl.envs.base import BatchedEnv, Obs

#: steps an evaluation episode may take on an env that declares no horizon; one still running then
#: counts as not successful
UNLIMITED_EPISODE_STEPS = 100_000


class ActingPolicy:
    """``obs -> actions`` of an agent (greedy unless ``explore``), told when episodes end, so a policy with
    per-episode state (a chunked policy's ensembled predictions) starts every episode afresh.

    Its random draws (a CEM's candidate actions, exploration noise) come from a generator of its own that each
    evaluation seeds with its ``seed`` (`ActingPolicy.start`), so the same checkpoint scores the same every time."""

    def __init__(self, agent: Any, explore: bool = False) -> None:
        self.agent, self.explore = agent, explore
        self.generator = torch.Generator(device=getattr(agent, "device", "cpu"))

    def start(self, seed: int) -> None:
        """Seed the acting draws for an evaluation that starts its env with ``seed``."""
        self.generator.manual_seed(seed)

    def __call__(self, obs: Obs) -> Any:
        return self.agent.act(obs, explore=self.explore, generator=self.generator)

    def episodes_ended(self, ended: torch.Tensor) -> None:
        episodes_ended(self.agent, ended)


def seed_acting(policy: Any, seed: int) -> None:
    """Seed ``policy``'s own random draws for an evaluation (a no-op for a plain function)."""
    start = getattr(policy, "start", None)
    if start is not None:
        start(seed)


def episodes_ended(policy: Any, ended: torch.Tensor) -> None:
    """Tell ``policy`` which copies' episodes just ended (a no-op for a plain function)."""
    notify = getattr(policy, "episodes_ended", None)
    if notify is not None:
        notify(ended)


@torch.no_grad()
def evaluate(policy: Callable[[Obs], torch.Tensor], env: BatchedEnv, seed: int, details: bool = False) -> dict[str, Any]:
    """Run one episode in each of ``env.num_envs`` copies with ``policy`` (greedy actions).

    The same ``seed`` gives the same start states and goals every time, so successive
    evaluations of a run are comparable. Success is ``info["is_success"]`` at the step the
    episode ends (on an env without a horizon, an episode still running after
    ``UNLIMITED_EPISODE_STEPS`` is not a success).

    Returns:
        ``success_rate``, ``eval_return`` (mean undiscounted) and ``eval_length`` (mean steps); with
        ``details``, also ``successes`` (how many) and ``returns`` (one per episode).
    """
    obs = env.reset(seed=seed)
    n = env.num_envs
    seed_acting(policy, seed)
    episodes_ended(policy, torch.ones(n, dtype=torch.bool, device=env.device))
    finished = torch.zeros(n, dtype=torch.bool, device=env.device)
    success = torch.zeros(n, dtype=torch.bool, device=env.device)
    returns = torch.zeros(n, device=env.device)
    lengths = torch.zeros(n, device=env.device)
    for _ in range(env.horizon or UNLIMITED_EPISODE_STEPS):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        active = ~finished
        returns += reward * active
        lengths += active.float()
        ended = (terminated | truncated) & active
        success |= ended & info["is_success"]
        finished |= ended
        if bool(finished.all()):
            break
    result: dict[str, Any] = {
        "success_rate": int(success.sum().item()) / n,  # an exact fraction of episodes (90 of 100 is 0.9)
        "eval_return": returns.mean().item(),
        "eval_length": lengths.mean().item(),
    }
    if details:
        result.update(successes=int(success.sum().item()), returns=returns.tolist())
    return result
