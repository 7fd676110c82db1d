"""The update-to-data limiter: gradient updates per collected env step held at a ratio, whatever the
speed of the collectors and of the trainer (Reverb's sample-to-insert rate limiter, in env steps)."""

from __future__ import annotations

__all__ = ["UpdateToDataLimiter"]


class UpdateToDataLimiter:
    """Says when the trainer may update and when a collector may be sent for more data.

    The updates a run owes at ``env_steps`` collected are

        owed(env_steps) = offline_updates + ratio * max(0, env_steps - learning_starts)

    The trainer updates while it has made fewer; a collector is sent out only while the updates owed
    once every call in flight (and this one) has returned exceed those made by at most
    ``ratio * lead_steps``: fast collectors wait for a slow trainer, a fast trainer waits for data.
    Collection starts once the ``offline_updates`` are made.

    Args:
        ratio: gradient updates per env step (``updates_per_step``).
        learning_starts: env steps before the first online update.
        offline_updates: updates on preloaded data before collection starts.
        lead_steps: env steps collection may run ahead of the trainer (the distributed loop passes two
            rounds of collect calls: ``CALLS_PER_COLLECTOR`` calls of every collector).
        enabled: False lets both run as fast as they can (updates still wait for ``learning_starts``).
    """

    def __init__(
        self, ratio: float, learning_starts: int, offline_updates: int = 0, lead_steps: int = 0, enabled: bool = True
    ) -> None:
        self.ratio, self.learning_starts, self.offline_updates = ratio, learning_starts, offline_updates
        self.lead_steps, self.enabled = lead_steps, enabled

    def nothing_to_sample(self, env_steps: int) -> None:
        """No batch can be drawn after ``env_steps`` (no episode has ended yet): owe no update for them, as the
        loop in one process makes none (otherwise collection waits for updates that wait for an episode)."""
        self.learning_starts = max(self.learning_starts, env_steps)

    def owed(self, env_steps: int) -> float:
        """Updates owed after ``env_steps`` collected env steps."""
        return self.offline_updates + self.ratio * max(0, env_steps - self.learning_starts)

    def may_update(self, updates: int, env_steps: int) -> bool:
        """Whether the trainer may make its next update."""
        if updates < self.offline_updates:
            return True
        if env_steps < self.learning_starts or self.ratio == 0:
            return False
        return not self.enabled or updates < self.owed(env_steps)

    def may_collect(self, updates: int, env_steps_after: int) -> bool:
        """Whether a collector may be sent, with ``env_steps_after`` the env steps once it and every
        call in flight return."""
        if updates < self.offline_updates:
            return False
        return not self.enabled or self.owed(env_steps_after) - updates <= self.ratio * self.lead_steps

    def ratio_made(self, updates: int, env_steps: int) -> float:
        """Online updates per env step since ``learning_starts`` (0 before)."""
        online = env_steps - self.learning_starts
        return (updates - self.offline_updates) / online if online > 0 else 0.0
