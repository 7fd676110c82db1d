"""Exploration by the env's scripted policy for a share of the training episodes (``--scripted-exploration``).

QT-Opt's first grasps came from a scripted policy that succeeded 15-30% of the time; learning then took over.
Here each training copy is, at the start of each of its episodes, handed to the env's ``scripted_action(obs)``
with probability ``share`` (during the first ``until`` env steps; 0: the whole run), otherwise the agent acts.
Whole episodes, not single steps, so the stored attempts are the scripted policy's own.
"""

from __future__ import annotations

import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.errors import ConfigError

__all__ = ["ScriptedExploration"]


class ScriptedExploration:
    """Chooses, per copy and episode, whether the env's scripted policy or the agent acts.

    Args:
        env: the training env; it must have ``scripted_action(obs) -> [num_envs, action_dim]``.
        share: the probability that an episode is scripted.
        until: env steps after which no new episode is scripted (0: never stop).
        generator: draws the choices.
    """

    def __init__(self, env: BatchedEnv, share: float, until: int, generator: torch.Generator) -> None:
        scripted = getattr(env, "scripted_action", None)
        if scripted is None:
            raise ConfigError("scripted_exploration", f"{type(env).__name__} has no scripted policy (envs with one: grasp)")
        self.scripted, self.share, self.until, self.generator = scripted, float(share), int(until), generator
        self.device = getattr(env, "device", torch.device("cpu"))
        self.active = self._draw(env.num_envs)

    def _draw(self, n: int) -> torch.Tensor:
        return torch.rand(n, generator=self.generator).to(self.device) < self.share

    def act(self, obs: Obs, agent_action: torch.Tensor) -> torch.Tensor:
        """The action of every copy: the scripted one where this episode is scripted."""
        if not bool(self.active.any()):
            return agent_action
        return torch.where(self.active[:, None], self.scripted(obs).to(agent_action), agent_action)

    def episodes_ended(self, done: torch.Tensor, env_steps: int) -> None:
        """Draw again for the copies whose episode ended (none scripted after ``until`` env steps)."""
        done = done.to(self.device)
        fresh = self._draw(len(done)) & torch.tensor(self.until == 0 or env_steps < self.until, device=self.device)
        self.active = torch.where(done, fresh, self.active)
