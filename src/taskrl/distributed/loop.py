"""The distributed off-policy loop: the trainer's side of collectors -> replay -> (Bellman updaters) -> trainer.

The trainer process keeps the replay, so a collector or updater that dies loses at most the work it
had in hand, never a stored episode. Each turn of the loop

1. sends idle collectors out for ``collector_steps`` steps of their env copies, when the limiter
   allows ([`UpdateToDataLimiter`][taskrl.distributed.limiter.UpdateToDataLimiter]);
2. stores the episodes of every collect call that came back;
3. learns: with Bellman updaters, keeps up to ``queue_size`` sampled batches being labelled or
   waiting, and regresses on labelled ones (``agent.regress(batch, y)``, QT-Opt's trainer); without,
   makes the agent's own update (``agent.update(batch)``: SAC, TD3, DQN, the Ape-X layout);
4. publishes acting and target weights every ``publish_interval`` updates, tagged with the update
   count (a role pulls them when the tag is newer than its own);
5. runs the bookkeeping (evaluation, metric rows with per-role figures, checkpoints).

Roles are called through a [`Pool`][taskrl.distributed.pools.Pool]: Ray actors, or the same role
objects in this process. The loop starts once every role is up, so all collectors' first calls
leave together; a role whose constructor raises stops the run with its reason
([`RoleCannotStart`][taskrl.distributed.pools.RoleCannotStart]) instead of being re-sent work forever.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any

import torch

from taskrl.distributed.limiter import UpdateToDataLimiter
from taskrl.distributed.pools import Pool, RoleDied, RoleRestarting
from taskrl.distributed.roles import Collected, Labelled
from taskrl.distributed.settings import DistributedConfig
from taskrl.replay.batch import Batch
from taskrl.replay.storage import EpisodeReplay
from taskrl.training.bookkeeping import Bookkeeping, LoopState

__all__ = ["DistributedLoop", "RoleMeters", "RolesLost"]

#: updates the trainer makes in a row before it looks at the collectors again
UPDATE_BURST = 32
#: collect calls queued on each collector: its next call waits in the actor, not for the trainer
CALLS_PER_COLLECTOR = 2
#: seconds the trainer waits for any role when it has nothing to do
IDLE_WAIT = 0.05
#: seconds the trainer waits for every role's process to start (import, env, agent) before it fails
ROLE_START_WAIT = 600.0
#: seconds a finishing run waits for the collect calls in flight and the collectors' running episodes
FINISH_WAIT = 60.0


class RolesLost(RuntimeError):
    """Every collector died and none has a restart left; the run's last checkpoint stays."""


def _cpu(tree: Any) -> Any:
    if isinstance(tree, torch.Tensor):
        return tree.detach().cpu()
    if isinstance(tree, dict):
        return {k: _cpu(v) for k, v in tree.items()}
    return tree


class RoleLives:
    """Deaths of each role of one kind, each counted once.

    A role's death shows either as a failed call (the first of its life to fail) or, when it died with
    no call in flight, as a result from a new process. ``epoch[i]`` counts role i's deaths. Calls carry
    the ``life[i]`` they were sent in, which moves on at each counted death and again when the new process
    first answers, so the other failed calls of a life add nothing. Calls sent after a counted death fail too
    while the new process starts (``restarting``: Ray's "unavailable"); they add nothing, also when they
    fail only after the new process has answered.
    """

    def __init__(self, size: int) -> None:
        self.epoch = [0] * size
        self.life = [0] * size
        self.pid: list[int | None] = [None] * size
        self.counted = [False] * size  # a death counted whose new process has not answered yet
        self.deaths = 0

    def failed(self, i: int, life: int, restarting: bool = False) -> None:
        if life == self.life[i] and not (restarting and self.counted[i]):
            self._death(i)
            self.counted[i] = True

    def answered(self, i: int, pid: int) -> None:
        if self.pid[i] is not None and pid != self.pid[i]:
            if not self.counted[i]:
                self._death(i)
            self.counted[i] = False
            self.life[i] += 1  # calls sent while it restarted belong to no life that can still die
        self.pid[i] = pid

    def _death(self, i: int) -> None:
        self.epoch[i] += 1
        self.life[i] += 1
        self.deaths += 1

    def out_of_restarts(self, i: int, max_restarts: int) -> bool:
        return max_restarts != -1 and self.epoch[i] > max_restarts


class RoleMeters:
    """Per-role figures since the last metrics row, and restart counts since the run started (the
    deaths its `RoleLives` counted).

    Args:
        collector_lives, updater_lives: the lives of each kind of role.
    """

    def __init__(self, collector_lives: RoleLives, updater_lives: RoleLives) -> None:
        self.collector_lives, self.updater_lives = collector_lives, updater_lives
        self.collectors, self.updaters = len(collector_lives.epoch), len(updater_lives.epoch)
        self.reset()

    @property
    def collector_restarts(self) -> int:
        return self.collector_lives.deaths

    @property
    def updater_restarts(self) -> int:
        return self.updater_lives.deaths

    def reset(self) -> None:
        self.steps = [0] * self.collectors
        self.collect_seconds = [0.0] * self.collectors
        self.targets = [0] * self.updaters
        self.label_seconds = [0.0] * self.updaters
        self.queue_depth = self.queue_samples = 0
        self.lag = self.lag_samples = 0
        self.staleness = self.staleness_max = self.staleness_samples = 0
        self.stale_dropped = 0

    def row(self, elapsed: float) -> dict[str, float]:
        """The row's per-role columns (see docs/distributed.md), then a fresh start."""
        out: dict[str, float] = {"collector/env_steps_per_s": sum(self.steps) / elapsed}
        for i, (n, s) in enumerate(zip(self.steps, self.collect_seconds)):
            out[f"collector{i}/env_steps_per_s"] = n / s if s > 0 else 0.0
        if self.updaters:
            out["updater/targets_per_s"] = sum(self.targets) / elapsed
            for j, (n, s) in enumerate(zip(self.targets, self.label_seconds)):
                out[f"updater{j}/targets_per_s"] = n / s if s > 0 else 0.0
            out["queue_depth"] = self.queue_depth / max(self.queue_samples, 1)
            out["target_staleness"] = self.staleness / max(self.staleness_samples, 1)
            out["target_staleness_max"] = self.staleness_max
            out["stale_batches_dropped"] = self.stale_dropped
        out["weight_lag"] = self.lag / max(self.lag_samples, 1)
        out["collector_restarts"] = self.collector_restarts
        if self.updaters:
            out["updater_restarts"] = self.updater_restarts
        self.reset()
        return out


class DistributedLoop:
    """Runs the trainer against collectors (and Bellman updaters) until ``total_steps``.

    Args:
        agent: the trainer's agent (``update``; with updaters also ``regress`` and ``bellman_parts``).
        replay: the trainer's episode storage (collected episodes arrive whole).
        sample_batch: ``() -> Batch``: a sampled and relabelled batch of the run's batch size.
        collectors: the Collector pool.
        updaters: the BellmanUpdater pool, or None (the trainer computes its own targets).
        settings: the ``cluster`` section.
        total_steps: env steps to collect.
        limiter: the update-to-data limiter.
        envs_per_collector: env copies of each collector.
        books: the run's bookkeeping.
    """

    def __init__(
        self,
        agent: Any,
        replay: EpisodeReplay,
        sample_batch: Callable[[], Batch],
        collectors: Pool,
        updaters: Pool | None,
        settings: DistributedConfig,
        total_steps: int,
        limiter: UpdateToDataLimiter,
        envs_per_collector: int,
        books: Bookkeeping,
    ) -> None:
        self.agent, self.replay, self.sample_batch = agent, replay, sample_batch
        self.collectors, self.updaters, self.settings = collectors, updaters, settings
        self.total_steps, self.limiter, self.books = total_steps, limiter, books
        self.call_steps = envs_per_collector * settings.collector_steps
        self.collector_lives = RoleLives(collectors.size)
        self.updater_lives = RoleLives(updaters.size if updaters else 0)
        self.meters = RoleMeters(self.collector_lives, self.updater_lives)
        self.collect_calls: dict[Any, tuple[int, int]] = {}  # handle -> (collector, its life when sent)
        # a free call slot of each collector; first back, first sent again
        self.idle = collections.deque(i for _ in range(CALLS_PER_COLLECTOR) for i in range(collectors.size))
        self.dead_collectors: set[int] = set()
        # steps of each collector's running episodes; lost when it dies
        self.running = [0] * collectors.size
        self.lost_env_steps = 0
        self.label_calls: dict[Any, tuple[int, int]] = {}  # handle -> (updater, its life when sent)
        self.labelled: collections.deque[Labelled] = collections.deque()
        self.live_updaters = list(range(updaters.size)) if updaters else []
        self._next_updater = 0
        self.version = -1
        self.acting_fetch = self.target_fetch = None

    # ---------------------------------------------------------------- weights
    def publish(self) -> None:
        """Acting weights (and, with updaters, target weights) tagged with the update count."""
        agent = self.agent
        self.version = agent.updates
        self.acting_fetch = self.collectors.publish(_cpu(agent.state_dict(agent.acting)))
        if self.live_updaters:
            self.target_fetch = self.updaters.publish(_cpu(agent.state_dict(agent.bellman_parts)))

    # ---------------------------------------------------------------- collection
    def in_flight_steps(self) -> int:
        return len(self.collect_calls) * self.call_steps

    def row_due(self, state: LoopState) -> bool:
        """A metrics row (or the end) is due: it waits for the updates owed so far, with collectors held."""
        return state.env_steps >= min(state.next_eval, self.total_steps)

    def dispatch(self, state: LoopState) -> None:
        if self.limiter.enabled and self.row_due(state):
            return
        while self.idle:
            ahead = state.env_steps + self.in_flight_steps()
            owed_at = self.data_steps(state) + self.in_flight_steps() + self.call_steps
            if ahead >= self.total_steps or not self.limiter.may_collect(state.updates, owed_at):
                return
            i = self.idle.popleft()
            handle = self.collectors.submit(
                i,
                "collect",
                self.settings.collector_steps,
                self.version,
                self.acting_fetch,
                state.env_steps,
                self.collector_lives.epoch[i],
            )
            self.collect_calls[handle] = (i, self.collector_lives.life[i])

    def harvest(self, handles: list[Any]) -> None:
        """Store what came back."""
        for handle in handles:
            i, life = self.collect_calls.pop(handle)
            try:
                got: Collected = self.collectors.result(handle)
            except RoleDied as error:
                self.collector_lives.failed(i, life, isinstance(error, RoleRestarting))
                self.lose_running(i)
                self.collector_lost(i)
                continue
            deaths = self.collector_lives.epoch[i]
            self.collector_lives.answered(i, got.pid)
            if self.collector_lives.epoch[i] != deaths:  # a new process: it died between calls, running episodes too
                self.lose_running(i)
            self.running[i] = got.running
            self.idle.append(i)
            self.store(got)
            self.meters.steps[i] += got.steps
            self.meters.collect_seconds[i] += got.seconds
            self.meters.lag += self.agent.updates - got.version
            self.meters.lag_samples += 1

    def lose_running(self, i: int) -> None:
        """Collector i died: the steps of its running episodes (counted in ``env_steps``) never reach the replay."""
        self.lost_env_steps += self.running[i]
        self.running[i] = 0

    def data_steps(self, state: LoopState) -> int:
        """Env steps whose transitions exist (stored, or in a live collector's running episodes): what the
        limiter owes updates for."""
        return state.env_steps - self.lost_env_steps

    def store(self, got: Collected) -> None:
        self.replay.add_episodes(got.episodes)
        self.books.add_steps(got.steps)
        self.books.add_episodes(torch.tensor(got.ended), torch.tensor(got.succeeded))

    def collector_lost(self, i: int) -> None:
        """A call of collector i failed: send it again (Ray restarts it) unless it has no restart left."""
        limit = self.settings.max_restarts
        if self.collector_lives.out_of_restarts(i, limit):
            if i in self.dead_collectors:
                return
            self.dead_collectors.add(i)
            if len(self.dead_collectors) == self.collectors.size:
                raise RolesLost(
                    f"every collector died and none has a restart left (max_restarts={limit}); "
                    f"the last checkpoint stays: continue with --resume"
                )
        else:
            self.idle.append(i)  # Ray restarts it; the next call waits for the new process

    # ---------------------------------------------------------------- learning
    def refill(self) -> None:
        """Keep ``queue_size`` batches labelled or being labelled (no more: back-pressure), sent
        ``batches_per_call`` at a time."""
        per_call = self.settings.batches_per_call
        while self.live_updaters and self.queued() + per_call <= self.settings.queue_size:
            j = self.live_updaters[self._next_updater % len(self.live_updaters)]
            self._next_updater += 1
            batches = [self.sample_batch().to("cpu") for _ in range(per_call)]
            handle = self.updaters.submit(j, "label_all", batches, self.version, self.target_fetch)
            self.label_calls[handle] = (j, self.updater_lives.life[j])

    def queued(self) -> int:
        """Batches labelled and waiting, or being labelled."""
        return len(self.labelled) + len(self.label_calls) * self.settings.batches_per_call

    def take_labels(self, timeout: float) -> None:
        for handle in self.updaters.ready(list(self.label_calls), timeout):
            j, life = self.label_calls.pop(handle)
            try:
                labelled: list[Labelled] = self.updaters.result(handle)
            except RoleDied as error:
                self.updater_lives.failed(j, life, isinstance(error, RoleRestarting))
                self.updater_lost(j)
                continue
            if labelled:
                self.updater_lives.answered(j, labelled[0].pid)
            self.labelled.extend(labelled)
            for got in labelled:
                self.meters.targets[j] += len(got.batch)
                self.meters.label_seconds[j] += got.seconds

    def updater_lost(self, j: int) -> None:
        """A call of updater j failed (its batches are dropped); stop sending to it once it has no restart left."""
        if self.updater_lives.out_of_restarts(j, self.settings.max_restarts) and j in self.live_updaters:
            self.live_updaters.remove(j)  # none left: the trainer computes its own targets

    def learn(self, state: LoopState) -> int:
        """Up to `UPDATE_BURST` updates while the limiter allows and batches are at hand."""
        made = 0
        device = self.agent.device
        while (
            made < UPDATE_BURST
            and self.replay.num_episodes > 0
            and self.limiter.may_update(state.updates, self.data_steps(state))
        ):
            if self.live_updaters:
                self.refill()
                if not self.labelled:
                    self.take_labels(0.0)
                if not self.labelled:
                    break
                self.meters.queue_depth += len(self.labelled)
                self.meters.queue_samples += 1
                got = self.labelled.popleft()
                stale = self.agent.updates - got.version  # updates since the weights behind these targets
                bound = self.settings.max_target_staleness
                if bound and stale > bound:  # too old to regress on: drop it (a fresh batch is labelled instead)
                    self.meters.stale_dropped += 1
                    continue
                self.meters.staleness += stale
                self.meters.staleness_max = max(self.meters.staleness_max, stale)
                self.meters.staleness_samples += 1
                metrics = self.agent.regress(got.batch.to(device), got.target.to(device))
            else:
                metrics = self.agent.update(self.sample_batch())
            self.books.add_update(metrics)
            made += 1
            if self.agent.updates - self.version >= self.settings.publish_interval:
                self.publish()
        if self.live_updaters and self.replay.num_episodes > 0:
            self.refill()
        return made

    # ---------------------------------------------------------------- the loop
    def wait(self) -> None:
        """Nothing to do: wait for the first role call of either kind to come back (or a short while), so
        labels that are ready never wait on a collect call still running."""
        if not self.collect_calls:
            if self.label_calls:
                self.take_labels(IDLE_WAIT)
            return
        # one wait over both kinds of call (the pools' handles are of one kind: Ray object refs, or done calls)
        ready = self.collectors.ready([*self.collect_calls, *self.label_calls], IDLE_WAIT)
        self.harvest([h for h in ready if h in self.collect_calls])
        if any(h in self.label_calls for h in ready):
            self.take_labels(0.0)

    def finish(self) -> None:
        """Keep every transition collected: the calls in flight, then each collector's running episodes."""
        while self.collect_calls:
            ready = self.collectors.ready(list(self.collect_calls), FINISH_WAIT)
            if not ready:
                break
            self.harvest(ready)
        for got in self.collectors.call_all("flush", FINISH_WAIT):
            self.store(got)

    def run(self, env_seed: int = 0) -> LoopState:
        """Train until ``total_steps`` env steps (and the updates they are owed) or an early stop."""
        books, state = self.books, self.books.state
        books.on_finish = self.finish
        books.row_metrics.append(self.row_metrics)
        for pool in (self.collectors, self.updaters):
            if pool is not None:
                pool.wait_started(ROLE_START_WAIT)
        self.publish()
        while True:
            if self.collect_calls:
                self.harvest(self.collectors.ready(list(self.collect_calls), 0.0))
            if self.replay.num_episodes == 0:
                self.limiter.nothing_to_sample(self.data_steps(state))
            self.dispatch(state)
            made = self.learn(state)
            if made == 0 and (
                state.env_steps < self.total_steps or self.limiter.may_update(state.updates, self.data_steps(state))
            ):
                self.wait()
            if self.row_due(state) and self.limiter.enabled and self.limiter.may_update(state.updates, self.data_steps(state)):
                continue  # a metrics row (and the end) comes once the updates owed so far are made
            if books.after_step(self.agent.exploration(state.env_steps)):
                break
        return books.close()

    def row_metrics(self, elapsed: float) -> dict[str, float]:
        state = self.books.state
        return {
            **self.meters.row(elapsed),
            "updates_per_env_step": self.limiter.ratio_made(state.updates, self.data_steps(state)),
            "lost_env_steps": self.lost_env_steps,
            "stored_episodes": self.replay.episodes_added,
        }
