"""The settings of a distributed run (the ``cluster`` section of ``config.json``); no Ray import here."""

from __future__ import annotations

import dataclasses
import re

from taskrl.errors import require

__all__ = ["DistributedConfig"]


@dataclasses.dataclass
class DistributedConfig:
    """Where the roles of an off-policy run live: one process, or Ray actors.

    Attributes:
        distributed: run collectors (and Bellman updaters) as Ray actors around the trainer, which
            keeps the replay; off: the same run in one process.
        collectors: Collector actors, each stepping its own env copies with the latest published weights.
        envs_per_collector: env copies per collector (0: ``num_envs // collectors``, at least 1, so the
            run steps as many copies as in one process).
        collector_steps: steps of each env copy per collect call; episodes carry over between calls.
        bellman_updaters: Bellman-updater actors computing targets for the trainer (QT-Opt's CEM targets);
            0: the trainer computes its own (the only layout for SAC, TD3 and DQN).
        queue_size: labelled batches waiting for the trainer or being labelled, at most (back-pressure:
            updaters never run further ahead than this).
        batches_per_call: batches an updater labels per call (fewer calls: less transfer work for the
            trainer per batch; at most ``queue_size``).
        publish_interval: trainer updates between publications of the acting and target weights.
        max_target_staleness: with Bellman updaters, drop (and count) a labelled batch whose targets were computed
            with weights more than this many trainer updates old (0: no bound; else at least ``publish_interval``,
            the age of the newest weights an updater can have).
        limit_updates: hold trainer updates per collected env step at ``updates_per_step``, by pausing
            the trainer or the collectors (off: both run as fast as they can).
        ray_address: empty: start a local Ray; ``auto`` or ``HOST:PORT``: join a running cluster.
        ray_cpus: logical CPUs of a local Ray (0: enough for every actor's ``actor_cpus``; roles mostly
            wait on envs, so more roles than cores is fine).
        actor_cpus: CPUs each collector and updater reserves in Ray's scheduler (e.g. 0.5 to fit 4 roles
            in ``ray_cpus=2``); a cluster with fewer is refused before the run starts.
        max_restarts: restarts of a collector or updater whose process died (-1: unlimited); the run
            keeps going while it is down.
    """

    distributed: bool = False
    collectors: int = 2
    envs_per_collector: int = 0
    collector_steps: int = 25
    bellman_updaters: int = 0
    queue_size: int = 8
    batches_per_call: int = 1
    publish_interval: int = 10
    max_target_staleness: int = 0
    limit_updates: bool = True
    ray_address: str = ""
    ray_cpus: int = 0
    actor_cpus: float = 1.0
    max_restarts: int = -1

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        for name in ("collectors", "collector_steps", "queue_size", "publish_interval", "batches_per_call"):
            require(getattr(self, name) >= 1, name, f"must be >= 1 (got {getattr(self, name)})")
        for name in ("envs_per_collector", "bellman_updaters", "ray_cpus"):
            require(getattr(self, name) >= 0, name, f"must be >= 0 (got {getattr(self, name)})")
        require(
            self.batches_per_call <= self.queue_size,
            "batches_per_call",
            f"must be <= queue_size={self.queue_size} (got {self.batches_per_call})",
        )
        require(
            self.max_target_staleness == 0 or self.max_target_staleness >= self.publish_interval,
            "max_target_staleness",
            f"must be 0 (no bound) or >= publish_interval={self.publish_interval}: newer targets cannot exist "
            f"(got {self.max_target_staleness})",
        )
        require(self.actor_cpus > 0, "actor_cpus", f"must be > 0 (got {self.actor_cpus})")
        require(self.max_restarts >= -1, "max_restarts", f"must be >= -1 (-1 = unlimited; got {self.max_restarts})")
        address = self.ray_address
        require(
            address in ("", "auto") or re.fullmatch(r"(ray://)?[\w.\-]+:\d{1,5}", address) is not None,
            "ray_address",
            f"must be empty (a local Ray), 'auto' or HOST:PORT (got {address!r})",
        )

    def envs_each(self, num_envs: int) -> int:
        """Env copies per collector for a run of ``num_envs`` copies."""
        return self.envs_per_collector or max(1, num_envs // self.collectors)
