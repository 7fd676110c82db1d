"""The roles of a distributed run as plain classes: they run in one process as they are, and as Ray
actors through [`taskrl.distributed.actors`][taskrl.distributed.actors] (``ray::Collector``, ``ray::BellmanUpdater``).

Neither keeps anything that a restart may not lose: a collector's unfinished episodes and an
updater's batch in flight are redone, while every finished episode already lives in the trainer's
replay. Weights come by version number: a role asks for the published weights (``fetch()``) only
when the version it is handed is newer than the one it holds, and never waits for the trainer.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeRecorder, Episodes

__all__ = ["BellmanUpdater", "Collected", "Collector", "Labelled", "pull_weights"]

Fetch = Callable[[], dict[str, Any]]


def pull_weights(role: Any, version: int, fetch: Fetch) -> None:
    """Load ``fetch()`` into ``role.agent`` when ``version`` is newer than the role's ``version``."""
    if version > role.version:
        role.agent.load_parts(fetch())
        role.version = version


def collector_seeds(entropy: list[int]) -> tuple[int, int]:
    """``(exploration seed, env seed)`` of a collector's life: two children of one ``SeedSequence(entropy)``, so the
    two random streams never coincide (seeding both with one integer made them the same stream)."""
    exploration, env = np.random.SeedSequence(entropy).spawn(2)
    return int(exploration.generate_state(1)[0]), int(env.generate_state(1)[0])


@dataclasses.dataclass
class Collected:
    """What one collect call returns.

    Attributes:
        episodes: the episodes that finished (as `EpisodeRecorder.drain` gives them).
        steps: env steps taken (all copies).
        ended, succeeded: training episodes that finished, and how many of them succeeded.
        seconds: wall-clock of the call.
        version: the weight version it acted with.
        pid: the collector's process (a new one after a restart).
        running: steps of the episodes still running after the call (counted in ``steps``, not yet returned:
            lost if the collector dies).
    """

    episodes: Episodes
    steps: int
    ended: int
    succeeded: int
    seconds: float
    version: int
    pid: int = dataclasses.field(default_factory=os.getpid)
    running: int = 0


@dataclasses.dataclass
class Labelled:
    """A batch with its Bellman targets, from an updater.

    Attributes:
        batch: the sampled (and relabelled) transitions.
        target: ``y`` per transition.
        seconds: wall-clock of computing the targets.
        version: the target-weight version they were computed with.
        pid: the updater's process (a new one after a restart).
    """

    batch: Batch
    target: torch.Tensor
    seconds: float
    version: int
    pid: int = dataclasses.field(default_factory=os.getpid)


class Collector:
    """Steps env copies with the agent's exploration and hands out finished episodes.

    Args:
        make_env: ``make_env(seed) -> BatchedEnv`` (this collector's copies).
        make_agent: ``make_agent(env) -> agent`` (the run's agent, acting only).
        seed: seed of this collector's envs and exploration.
        threads: torch CPU threads of this process (0: torch's default).
    """

    def __init__(self, make_env: Callable[[int], Any], make_agent: Callable[[Any], Any], seed: int, threads: int = 1) -> None:
        if threads:
            torch.set_num_threads(threads)
        self.seed, self.make_env = seed, make_env
        self.env = make_env(seed)
        self.agent = make_agent(self.env)
        self.recorder = EpisodeRecorder(
            self.env.single_observation_space, self.env.single_action_space, self.env.num_envs, horizon=self.env.horizon
        )
        self.generator = torch.Generator()
        self.version = -1
        self.epoch = 0
        self.obs = None

    def pid(self) -> int:
        """This process's id (what an operator or a fault test signals)."""
        return os.getpid()

    def _start(self, epoch: int, env_steps: int) -> None:
        """Reset the envs of a new process. Its first life (epoch 0, the run's start) draws its seeds from the
        collector's seed alone, so a run is reproduced; any later start (a restart, whenever it died; a resumed run)
        from (seed, epoch, the run's env steps), so no life repeats another's episodes."""
        self.epoch = epoch
        entropy = [self.seed] if epoch == 0 and env_steps == 0 else [self.seed, epoch, env_steps]
        generator_seed, env_seed = collector_seeds(entropy)
        self.generator.manual_seed(generator_seed)
        self.obs = self.env.reset(seed=env_seed)
        self.recorder.start(self.obs)

    def collect(self, steps: int, version: int, fetch: Fetch, env_steps: int = 0, epoch: int = 0) -> Collected:
        """Take ``steps`` steps of every env copy; pull weights first if ``version`` is newer.

        Args:
            steps: steps per env copy.
            version: the newest published weight version.
            fetch: ``() -> acting weights`` of that version (called only when they are newer).
            env_steps: the run's env steps, for exploration schedules.
            epoch: how many times the trainer saw this collector restart (seeds a new process).
        """
        started = time.perf_counter()
        pull_weights(self, version, fetch)
        if self.obs is None:  # a new process: the envs of a running one are never reset (their steps are counted)
            self._start(epoch, env_steps)
        env, recorder = self.env, self.recorder
        ended = succeeded = 0
        obs = self.obs
        for t in range(steps):
            action = self.agent.act(obs, explore=True, generator=self.generator, env_steps=env_steps + t * env.num_envs)
            next_obs, reward, terminated, truncated, info = env.step(action)
            recorder.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
            done = terminated | truncated
            ended += int(done.sum())
            succeeded += int((done & info["is_success"]).sum())
            obs = next_obs
        self.obs = obs
        seconds = time.perf_counter() - started
        return Collected(
            recorder.drain(), steps * env.num_envs, ended, succeeded, seconds, self.version, running=recorder.running_steps
        )

    def flush(self) -> Collected:
        """The episodes still running, stored as cut at their last step (``truncated`` there): what a
        run that stops keeps of them."""
        started = time.perf_counter()
        self.recorder.cut_running()
        return Collected(self.recorder.drain(), 0, 0, 0, time.perf_counter() - started, self.version)

    def close(self) -> None:
        self.env.close()


class BellmanUpdater:
    """Computes Bellman targets for sampled batches with the target weights it was last sent.

    Args:
        make_agent: ``() -> agent`` with ``bellman_target(batch, generator)`` and ``bellman_parts``.
        seed: seed of its CEM sampling.
        threads: torch CPU threads of this process (0: torch's default).
    """

    def __init__(self, make_agent: Callable[[], Any], seed: int, threads: int = 1) -> None:
        if threads:
            torch.set_num_threads(threads)
        self.agent = make_agent()
        self.generator = torch.Generator(device=self.agent.device)
        self.generator.manual_seed(seed)
        self.version = -1

    def pid(self) -> int:
        """This process's id."""
        return os.getpid()

    def label(self, batch: Batch, version: int, fetch: Fetch) -> Labelled:
        """``y`` for every transition of ``batch``, with the target weights of ``version`` (pulled by
        ``fetch()`` when newer than those held)."""
        started = time.perf_counter()
        pull_weights(self, version, fetch)
        target = self.agent.bellman_target(batch, self.generator)
        return Labelled(batch, target, time.perf_counter() - started, self.version)

    def label_all(self, batches: list[Batch], version: int, fetch: Fetch) -> list[Labelled]:
        """`label` of each batch, in one call (one transfer each way for all of them)."""
        return [self.label(batch, version, fetch) for batch in batches]
