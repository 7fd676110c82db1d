"""Distributed off-policy training: roles, limiter, queue, replay, faults, offline-then-online.

The first tests run the roles in this process (a LocalPool: no Ray); the last ones start a local Ray
with 2 CPUs, train PointReach with collectors and a Bellman updater, and SIGKILL role processes.
"""

import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch

import taskrl
from helpers import small_run
from taskrl.config import ConfigError
from taskrl.distributed.limiter import UpdateToDataLimiter
from taskrl.distributed.loop import DistributedLoop, RoleLives, RolesLost
from taskrl.distributed.pools import LatePool, LocalPool, RoleCannotStart, RoleDied, RoleRestarting
from taskrl.distributed.roles import BellmanUpdater, Collector
from taskrl.logger import read_metrics
from taskrl.overrides import with_overrides
from taskrl.presets import preset_config
from taskrl.replay import EpisodeRecorder, EpisodeReplay, RecentMixSampler
from taskrl.run import build
from taskrl.runmodes.distributed import collector_env, role_agent
from taskrl.training.bookkeeping import Bookkeeping, LoopState
from taskrl.training.offpolicy import batch_sampler
from taskrl.wiring.parts import make_evaluator

#: tests that start Ray or look for its role processes: one after another in one test worker (``make test`` runs
#: two), so two local clusters never share the 2 CPUs and a SIGKILL never reaches another test's roles
ON_RAY = pytest.mark.xdist_group("ray")

# ---------------------------------------------------------------------- pieces, in one process


def test_the_limiter_holds_updates_to_the_ratio_both_ways():
    limiter = UpdateToDataLimiter(ratio=0.25, learning_starts=100, lead_steps=40)
    assert not limiter.may_update(0, 99)  # before learning starts
    assert limiter.may_update(0, 104) and not limiter.may_update(1, 104)  # 0.25 * 4 = 1 owed
    assert limiter.may_collect(0, 140)  # 10 owed: within the lead of 0.25 * 40
    assert not limiter.may_collect(0, 141)  # a slow trainer holds the collectors back
    unlimited = UpdateToDataLimiter(ratio=0.25, learning_starts=100, lead_steps=40, enabled=False)
    assert unlimited.may_update(10**6, 101) and unlimited.may_collect(0, 10**9)
    offline = UpdateToDataLimiter(ratio=0.25, learning_starts=0, offline_updates=50)
    assert offline.may_update(49, 0) and not offline.may_collect(49, 10)  # offline updates first
    assert offline.may_collect(50, 0)


def _config(**overrides):
    base = dict(
        total_steps=3_000,
        eval_interval=1_000,
        eval_episodes=20,
        threads=1,
        seed=0,
        learning_starts=500,
        checkpoint_interval=10**6,
    )
    return with_overrides(preset_config("pointreach-qtopt-her"), {**base, **overrides})


def test_a_collectors_episodes_equal_those_an_in_process_replay_stores():
    config = _config(num_envs=4)
    env = collector_env(config, None, 4, seed=3)
    agent = role_agent(config, env)
    space, action_space = env.single_observation_space, env.single_action_space
    recorder = EpisodeRecorder(space, action_space, 4, horizon=env.horizon)
    direct = EpisodeReplay(space, action_space, 10_000, num_envs=4, horizon=env.horizon)
    via = EpisodeReplay(space, action_space, 10_000, num_envs=4, horizon=env.horizon)
    obs = env.reset(seed=3)
    recorder.start(obs), direct.start(obs)
    g = torch.Generator().manual_seed(0)
    for _ in range(120):
        action = agent.act(obs, explore=True, generator=g)
        obs, reward, terminated, truncated, info = env.step(action)
        for r in (recorder, direct):
            r.add(action, reward, terminated, truncated, info["final_obs"], obs)
    via.add_episodes(recorder.drain())
    assert via.num_episodes == direct.num_episodes == via.episodes_added > 0
    got, expected = via.episodes(), direct.episodes()
    for key in ("action", "reward", "terminated", "truncated", "lengths"):
        assert torch.equal(getattr(got, key), getattr(expected, key)), key
    for key in expected.obs:
        assert torch.equal(got.obs[key], expected.obs[key]), key
    assert recorder.drain().num_episodes == 0  # drained once


def test_recent_mix_draws_its_share_from_the_newest_episodes():
    config = _config(num_envs=2)
    env = collector_env(config, None, 2, seed=0)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space, 50 * 40, num_envs=2, horizon=env.horizon)
    obs = env.reset(seed=0)
    replay.start(obs)
    for _ in range(env.horizon * 10):  # 20 episodes
        action = torch.rand(2, 2) * 2 - 1
        obs, reward, terminated, truncated, info = env.step(action)
        replay.add(action, reward, terminated, truncated, info["final_obs"], obs)
    newest = set(replay.newest_episodes(4).tolist())
    sampler = RecentMixSampler(replay, recent_fraction=0.25, recent_episodes=4)
    batch = sampler(400, torch.Generator().manual_seed(0))
    assert set(batch.episode[:100].tolist()) <= newest  # the window's share comes first
    assert len(set(batch.episode[100:].tolist()) - newest) > 5  # the rest from all stored episodes


def _local_loop(tmp_path, config, updaters: int, evaluated: bool = False, pool=LocalPool):
    """A DistributedLoop whose roles are plain objects in this process (``pool``: a LocalPool, or a LatePool whose
    calls come back late and out of order), with its bookkeeping (evaluating the trainer's agent, or a stand-in)."""
    parts = build(config)
    evaluate = make_evaluator(config, parts.eval_env, parts.agent, seed=123)[0] if evaluated else lambda: {"success_rate": 0.0}
    each = config.cluster.envs_each(config.num_envs)
    collectors = pool(
        [
            Collector(lambda seed: collector_env(config, None, each, seed), lambda env: role_agent(config, env), 10 + i)
            for i in range(2)
        ]
    )
    labellers = pool([BellmanUpdater(lambda: role_agent(config), 20 + j) for j in range(updaters)]) if updaters else None
    limiter = UpdateToDataLimiter(
        config.updates_per_step, config.learning_starts, lead_steps=2 * each * config.cluster.collector_steps
    )
    rows = []
    books = Bookkeeping(
        LoopState(),
        evaluate,
        rows.append,
        lambda state: None,
        config.total_steps,
        config.evaluation.eval_interval,
        config.checkpoints.checkpoint_interval,
        config.evaluation.stop_at_success,
        parts.device,
    )
    sample = batch_sampler(parts.sampler, config.batch_size, parts.generator)
    loop = DistributedLoop(
        parts.agent, parts.replay, sample, collectors, labellers, config.cluster, config.total_steps, limiter, each, books
    )
    return loop, rows, parts


@pytest.mark.timeout(120)
def test_updates_are_owed_from_the_first_stored_episode_not_from_learning_starts(tmp_path):
    """learning_starts below the end of the first episodes: no update can be made before an episode is stored,
    so none is owed (else collection waits for updates that wait for an episode, for ever)."""
    config = _config(num_envs=2, learning_starts=0, collector_steps=4, total_steps=160, batch_size=8, hidden_sizes=(16,))
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0)
    state = loop.run()
    parts.close()
    horizon = parts.env.horizon
    assert state.env_steps >= 160
    # owed from the first stored episode on (the run's copies end theirs together), updates_per_step per env step
    first = config.num_envs * (horizon - 1)
    assert 0 < state.updates <= config.updates_per_step * (state.env_steps - first) + 1


@pytest.mark.slow
def test_the_loop_keeps_the_update_to_data_ratio_and_a_bounded_queue(tmp_path):
    config = _config(collectors=2, bellman_updaters=2, queue_size=5, batches_per_call=2)
    loop, rows, parts = _local_loop(tmp_path, config, updaters=2, pool=LatePool)  # calls late and out of order
    most, leads = [], []
    refill, dispatch = loop.refill, loop.dispatch

    def watched_refill():
        refill()
        most.append(loop.queued())

    def watched_dispatch(state):
        dispatch(state)  # the updates owed once every call out returns, beyond those made: the limiter's lead
        leads.append(loop.limiter.owed(state.env_steps + loop.in_flight_steps()) - state.updates)

    loop.refill, loop.dispatch = watched_refill, watched_dispatch
    state = loop.run()
    assert state.env_steps >= config.total_steps
    assert max(most) <= config.cluster.queue_size  # back-pressure: never more batches out than the queue holds
    assert max(leads) <= config.updates_per_step * loop.limiter.lead_steps  # collection never ran further ahead
    for row in rows:
        if row["env_steps"] > config.learning_starts:
            assert row["updates_per_env_step"] == pytest.approx(config.updates_per_step, rel=0.05), row
    assert rows[-1]["updater/targets_per_s"] > 0 and rows[-1]["stored_episodes"] <= parts.replay.episodes_added
    assert parts.replay.num_transitions == state.env_steps  # every collected step is stored (flushed at the end)
    # targets computed with weights some updates old, and how old, in every row
    assert all(0 <= r["target_staleness"] <= r["target_staleness_max"] for r in rows)
    assert any(r["target_staleness_max"] >= 1 for r in rows)
    parts.close()


def test_each_death_of_a_role_counts_once_with_or_without_a_call_in_flight():
    lives = RoleLives(2)
    lives.answered(0, pid=100), lives.answered(0, pid=100)
    lives.answered(0, pid=101)  # killed while idle: only its new process shows it
    assert lives.deaths == 1 and lives.epoch == [1, 0]
    sent = lives.life[0]
    lives.failed(0, sent), lives.failed(0, sent)  # two calls of one life fail
    lives.answered(0, pid=102)  # ... and its next process answers: the same death
    lives.failed(1, lives.life[1])
    assert lives.deaths == 3 and lives.epoch == [2, 1]
    assert lives.out_of_restarts(0, max_restarts=1) and not lives.out_of_restarts(1, max_restarts=1)


def test_calls_that_fail_while_a_role_restarts_count_no_other_death():
    # Ray fails the calls in hand at a kill and those sent before the new process is up alike ("unavailable")
    lives = RoleLives(1)
    lives.answered(0, pid=100)
    lives.failed(0, lives.life[0], restarting=True)  # killed with a call in hand
    while_restarting = lives.life[0]
    lives.failed(0, while_restarting, restarting=True), lives.failed(0, while_restarting, restarting=True)
    assert lives.deaths == 1 and lives.epoch == [1]
    lives.answered(0, pid=101)
    lives.failed(0, while_restarting, restarting=True)  # sent while it restarted, failing after its new process answered
    assert lives.deaths == 1
    lives.failed(0, lives.life[0], restarting=True)  # killed again, after its new process answered
    lives.failed(0, lives.life[0])  # and a death Ray reports as final (no restart left) counts too
    assert lives.deaths == 3 and lives.epoch == [3]


def test_a_died_call_is_a_restart_while_ray_still_restarts_the_role():
    # a call that reaches the dead process before Ray marks it restarting fails as "died", not "unavailable":
    # Ray's actor table decides (a second count of one kill was seen on a loaded machine)
    from types import SimpleNamespace

    from taskrl.distributed.actors import RayPool

    class ActorError(Exception):
        actor_init_failed = False
        actor_id = "a1"

    class Unavailable(ActorError):
        pass

    def pool_seeing(state):
        def actors(actor_id):
            if state is None:
                raise RuntimeError("no table")
            return {"State": state}

        def get(ref):
            raise ActorError("The actor died unexpectedly before finishing this task.")

        ray = SimpleNamespace(
            get=get,
            exceptions=SimpleNamespace(RayActorError=ActorError, ActorUnavailableError=Unavailable),
            _private=SimpleNamespace(state=SimpleNamespace(actors=actors)),
        )
        pool = RayPool.__new__(RayPool)
        pool.ray, pool.name = ray, "BellmanUpdater"
        return pool

    for state in ("RESTARTING", "ALIVE"):  # ALIVE: Ray's table not yet told
        with pytest.raises(RoleRestarting):
            pool_seeing(state).result(None)
    for state in ("DEAD", None):  # no restart left, or no table to read: a death
        with pytest.raises(RoleDied) as err:
            pool_seeing(state).result(None)
        assert not isinstance(err.value, RoleRestarting)


class _DyingCollector:
    """A collector whose process dies at every call."""

    def collect(self, *args):
        raise RoleDied("killed")


def test_labels_older_than_the_staleness_bound_are_dropped_and_counted(tmp_path):
    config = _config(
        collectors=2, bellman_updaters=2, queue_size=8, publish_interval=2, max_target_staleness=2, total_steps=1_000
    )
    loop, rows, parts = _local_loop(tmp_path, config, updaters=2)
    loop.run()
    parts.close()
    used = [row for row in rows if row.get("target_staleness_max") is not None and row["updates"] > 0]
    assert used and max(row["target_staleness_max"] for row in used) <= 2  # never regressed on older targets
    assert sum(row["stale_batches_dropped"] for row in used) > 0  # a queue of 8 runs older: those were dropped
    assert parts.agent.updates > 0


def _collector(config, seed: int) -> Collector:
    """A new collector process (Ray's restart runs the constructor again with the same arguments)."""
    return Collector(lambda s: collector_env(config, None, 2, s), lambda env: role_agent(config, env), seed)


def test_a_new_collector_process_never_replays_another_lifes_episodes():
    config = _config(num_envs=2)
    none = lambda: None  # noqa: E731 - no weights newer than the collector's own
    first = _collector(config, 10).collect(60, -1, none, 0, 0).episodes
    again = _collector(config, 10).collect(60, -1, none, 0, 0).episodes  # the run's start: seeded as it always was
    assert torch.equal(first.obs["observation"][0], again.obs["observation"][0])
    # killed between calls: its new process is called before the trainer has counted the death (epoch 0)
    between = _collector(config, 10).collect(60, -1, none, 120, 0).episodes
    after_a_failed_call = _collector(config, 10).collect(60, -1, none, 120, 1).episodes
    starts = [e.obs["observation"][0] for e in (first, between, after_a_failed_call)]
    assert not torch.equal(starts[0], starts[1]) and not torch.equal(starts[1], starts[2])


def test_a_running_collector_keeps_its_episodes_when_the_trainer_counts_a_death():
    """The trainer counts a death between calls when the new process first answers; that process's envs
    (whose steps are counted) are not reset by the next call's new epoch."""
    config = _config(num_envs=2)
    collector = _collector(config, 10)
    assert collector.collect(30, -1, lambda: None, 0, 0).episodes.num_episodes == 0  # 30 of 50 steps
    got = collector.collect(30, -1, lambda: None, 60, 1)
    assert got.episodes.num_episodes == 2 and got.episodes.lengths.tolist() == [50, 50]
    assert got.running == 2 * 10


class _DiesOnce:
    """A collector whose process dies during its second call, with episodes running; Ray's restart is a new one."""

    def __init__(self, make) -> None:
        self.make, self.role, self.calls, self.lost = make, make(), 0, 0

    def collect(self, *args):
        self.calls += 1
        if self.calls == 2:
            self.lost = self.role.recorder.running_steps + args[0] * self.role.env.num_envs  # and the call's own
            self.role = self.make()
            raise RoleDied("killed")
        return self.role.collect(*args)

    def flush(self):
        return self.role.flush()


def test_steps_lost_with_a_dead_collector_are_counted_apart_and_owe_no_update(tmp_path):
    config = _config(num_envs=4, learning_starts=0, collector_steps=20, total_steps=600, batch_size=8, hidden_sizes=(16,))
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0)
    dying = _DiesOnce(lambda: _collector(config, 10))
    loop.collectors = LocalPool([dying, _collector(config, 11)])
    state = loop.run()
    parts.close()
    # the steps of the failed call never counted; those of the episodes running before it are counted and lost
    running_before = dying.lost - config.cluster.collector_steps * 2
    assert running_before > 0 and loop.lost_env_steps == running_before
    # every counted step is stored (the live collectors' running episodes flushed at the end) or counted lost
    assert parts.replay.num_transitions + parts.replay.evicted_transitions == state.env_steps - loop.lost_env_steps
    assert rows[-1]["lost_env_steps"] == running_before


class _DiesBetweenCalls:
    """A collector whose process dies after its first call, idle: the next call reaches a new process (a new pid)."""

    def __init__(self, make) -> None:
        self.make, self.role, self.calls, self.running_at_death = make, make(), 0, 0

    def collect(self, *args):
        self.calls += 1
        if self.calls == 2:
            self.running_at_death = self.role.recorder.running_steps
            self.role = self.make()
        got = self.role.collect(*args)
        return dataclasses.replace(got, pid=got.pid + 1_000_000) if self.calls >= 2 else got

    def flush(self):
        return self.role.flush()


def test_steps_running_when_a_collector_dies_between_calls_are_counted_lost(tmp_path):
    """Mutation: no ``lose_running`` when a new process answers (distributed/loop.py) leaves them uncounted: fails."""
    config = _config(num_envs=4, learning_starts=0, collector_steps=20, total_steps=600, batch_size=8, hidden_sizes=(16,))
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0)
    dying = _DiesBetweenCalls(lambda: _collector(config, 10))
    loop.collectors = LocalPool([dying, _collector(config, 11)])
    state = loop.run()
    parts.close()
    assert dying.running_at_death > 0 and loop.lost_env_steps == dying.running_at_death
    assert loop.meters.collector_restarts == 1
    assert parts.replay.num_transitions + parts.replay.evicted_transitions == state.env_steps - loop.lost_env_steps


def test_collectors_out_of_restarts_end_the_run_with_one_error(tmp_path):
    config = _config(collectors=2, max_restarts=1)
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0)
    loop.collectors = LocalPool([_DyingCollector(), _DyingCollector()])
    with pytest.raises(RolesLost, match="max_restarts=1"):
        loop.run()
    assert loop.meters.collector_restarts == 4  # each died twice: its first life and its one restart
    parts.close()


class _DyingUpdater:
    """An updater whose process dies at every call."""

    def label_all(self, *args):
        raise RoleDied("killed")


@pytest.mark.slow
def test_updaters_out_of_restarts_leave_the_targets_to_the_trainer(tmp_path):
    config = _config(collectors=2, bellman_updaters=1, max_restarts=0, total_steps=1_500)
    loop, rows, parts = _local_loop(tmp_path, config, updaters=1)
    loop.updaters = LocalPool([_DyingUpdater()])
    state = loop.run()
    assert loop.live_updaters == [] and loop.meters.updater_restarts == 1
    assert state.env_steps >= config.total_steps and state.updates >= 0.25 * (config.total_steps - 500) - 1
    parts.close()


@pytest.mark.slow
def test_sac_learns_through_collectors_with_its_own_targets(tmp_path):
    # the Ape-X layout: collectors feed the trainer's replay and SAC makes its whole update itself, at the
    # settings of tests/test_learning.py's in-process run (random: ~0.05)
    config = with_overrides(
        preset_config("pointreach-sac-her"),
        {"total_steps": 21_000, "stop_at_success": 0.9, "collectors": 2, "eval_episodes": 20, "threads": 1, "seed": 0},
    )
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0, evaluated=True)
    state = loop.run()
    assert rows[-1]["success_rate"] >= 0.9, [r["success_rate"] for r in rows]
    assert state.env_steps < config.total_steps  # stopped at success
    assert rows[-1]["weight_lag"] < config.cluster.publish_interval + 32


@pytest.mark.slow
def test_data_sharing_runs_through_collectors(tmp_path):
    """The trainer samples with the run's TaskSharing: the grid's low-data task is learnt from the
    other tasks' data that collectors send, and the shares are logged.

    The low-data task's success swings between evaluations (20 episodes each; 0.3 to 0.8 one row apart) and
    with the floating-point rounding of the machine's matrix products, so the test reads the last two
    evaluations of a 12,000-step run: their mean was 0.75 to 0.95 over seeds 0-9 on one machine; a random
    policy reaches about 0.05."""
    config = with_overrides(
        preset_config("grid-sharing-dqn"),
        {"collectors": 2, "bellman_updaters": 0, "total_steps": 12_000, "threads": 1, "seed": 0},
    )  # not --distributed: that would start a local Ray; the roles here are plain objects
    loop, rows, parts = _local_loop(tmp_path, config, updaters=0, evaluated=True)
    names = list(parts.env.task_set.names)
    loop.books.row_metrics.append(lambda elapsed: parts.sharing.metrics(names))
    try:
        loop.run()
    finally:
        parts.close()
    assert parts.sharing is not None and parts.sampler.draw is parts.sharing
    assert rows[-1]["shared/top-left-avoid"] == pytest.approx(0.5, abs=0.03)
    last_two = [r["success/top-left-avoid"] for r in rows[-2:]]
    assert sum(last_two) / 2 >= 0.7, [r["success/top-left-avoid"] for r in rows]


def test_distribution_settings_are_checked():
    with pytest.raises(ConfigError) as err:
        taskrl.train("pointreach-sac-her", distributed=True, bellman_updaters=1)
    assert err.value.field == "bellman_updaters" and "qtopt" in err.value.message
    with pytest.raises(ConfigError) as err:
        taskrl.train("pointreach-sac-her", algo="ppo", distributed=True)
    assert err.value.field == "distributed"
    with pytest.raises(ConfigError) as err:
        taskrl.train("pointreach-qtopt-her", offline_updates=10)
    assert err.value.field == "offline_updates"
    with pytest.raises(ConfigError) as err:
        taskrl.train("pointreach-qtopt-her", distributed=True, ray_address="not an address")
    assert err.value.field == "ray_address"


@pytest.mark.slow
@ON_RAY
def test_more_actors_than_the_cluster_can_place_are_refused_not_waited_for(tmp_path, monkeypatch):
    # no --ray-address is a local Ray of the run's own, whatever cluster RAY_ADDRESS (or a `ray start`) names
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:9")
    with pytest.raises(ConfigError) as err:
        taskrl.train("pointreach-qtopt-her", out=tmp_path / "run", distributed=True, collectors=3, bellman_updaters=1, ray_cpus=2)
    assert err.value.field == "actor_cpus" and "need 4 CPUs" in err.value.message
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
@ON_RAY
def test_a_role_that_cannot_start_stops_the_run_with_its_reason(tmp_path, monkeypatch):
    # a module the trainer imports but the roles' processes cannot, as on cluster nodes that lack it: Ray never
    # restarts a role whose constructor raised, so re-sending it work would spin for ever
    lines = ["import os", "if os.environ['TRAINER_PID'] != str(os.getpid()):", "    raise ImportError('not on this node')"]
    (tmp_path / "trainer_only.py").write_text("\n".join(lines) + "\n")
    monkeypatch.syspath_prepend(tmp_path)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("TRAINER_PID", str(os.getpid()))
    with pytest.raises(RoleCannotStart, match="Collector 0 could not start: .*cannot import 'trainer_only': not on this node"):
        small_run(
            "pointreach-qtopt-her",
            tmp_path / "run",
            env_module="trainer_only",
            distributed=True,
            collectors=2,
            ray_cpus=2,
            total_steps=2_000,
        )
    import ray

    assert not ray.is_initialized()  # the run's Ray is shut down on the way out


@pytest.mark.slow
def test_an_unreachable_cluster_is_one_line_and_exit_2(tmp_path):
    out = tmp_path / "run"
    done = subprocess.run(
        [sys.executable, "-m", "taskrl.cli", "train", "pointreach-qtopt-her", "--distributed", "--ray-address", "127.0.0.1:9"]
        + ["--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "RAY_ADDRESS": ""},
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "--ray-address" in done.stderr
    assert not out.exists()  # nothing left behind


def test_auto_that_finds_no_cluster_is_one_error_not_a_wait(monkeypatch):
    # Ray's own lookup, made to find nothing (a subprocess running the real one would join whatever Ray is
    # up on the machine at the time: another run's, or one still shutting down)
    import ray
    import ray._private.services as services

    from taskrl.distributed.actors import start_ray
    from taskrl.distributed.settings import DistributedConfig

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(services, "_find_address_from_flag", lambda flag: set())
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir: None)
    services.find_gcs_addresses.cache_clear()
    started = time.monotonic()
    with pytest.raises(ConfigError) as err:
        start_ray(DistributedConfig(ray_address="auto"), actors=2)
    assert err.value.field == "ray_address" and "no running Ray cluster was found" in err.value.message
    assert "\n" not in err.value.message and time.monotonic() - started < 10
    assert not ray.is_initialized()


def test_auto_that_finds_a_gone_clusters_address_is_one_error_not_a_wait(monkeypatch):
    # processes left over from a cluster that is gone still name its address; Ray's core would try it for 60 s
    # and abort the process
    import ray
    import ray._private.services

    from taskrl.distributed.actors import start_ray
    from taskrl.distributed.settings import DistributedConfig

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray._private.services, "canonicalize_bootstrap_address", lambda address: "127.0.0.1:9")
    started = time.monotonic()
    with pytest.raises(ConfigError) as err:
        start_ray(DistributedConfig(ray_address="auto"), actors=2)
    assert err.value.field == "ray_address" and "127.0.0.1:9" in err.value.message and "found by 'auto'" in err.value.message
    assert time.monotonic() - started < 10


@pytest.mark.slow
def test_offline_data_from_another_run_then_online(tmp_path):
    # a run that only acts at random (no update: learning never starts) leaves its replay ...
    random = dict(random_action_prob=1.0, random_action_prob_end=1.0)
    source = small_run(
        "pointreach-qtopt-her",
        tmp_path / "explore",
        total_steps=8_000,
        learning_starts=10**6,
        threads=1,
        **random,
    )
    assert source.metrics["success_rate"] < 0.1
    # ... which another run learns from before it collects: offline updates, then a short online phase
    short = dict(total_steps=800, learning_starts=0, eval_interval=10**6, threads=1, tensorboard=False, seed=0)
    common = dict(offline_data=str(tmp_path / "explore"), **short)
    run = taskrl.train("pointreach-qtopt-her", out=tmp_path / "offline", offline_updates=2_500, **common)
    assert run.metrics["updates"] >= 2_500 + 0.25 * 800 - 1
    assert run.metrics["success_rate"] >= 0.9  # random data alone, learned offline
    online_only = taskrl.train("pointreach-qtopt-her", out=tmp_path / "online", **common)
    assert online_only.metrics["success_rate"] < 0.5  # the same data and budget, without the offline updates


# ---------------------------------------------------------------------- on Ray (2 CPUs)


def _role_pids(name: str) -> list[int]:
    """Processes whose title is ``ray::<name>`` (what Ray names an actor's process) started by this one (a local
    Ray's workers are its raylet's children): never a role of another program's Ray on the same machine."""
    titles, parents = {}, {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
                titles[int(entry.name)] = (entry / "cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
            except OSError:
                continue
            parents[int(entry.name)] = int(stat[stat.rindex(")") + 2 :].split()[1])  # after "pid (name) state"

    def descends(pid: int) -> bool:
        while pid in parents and pid > 1:
            pid = parents[pid]
            if pid == os.getpid():
                return True
        return False

    return [pid for pid, title in titles.items() if title.startswith(f"ray::{name}") and descends(pid)]


@pytest.mark.slow
@pytest.mark.timeout(900)  # about 2 minutes on 2 idle cores; 13 on cores shared with two benchmark runs
@ON_RAY
def test_distributed_qtopt_survives_killed_roles_and_reaches_the_in_process_success(tmp_path):
    """The settings and goal of tests/test_learning.py's in-process run, on 2 collectors and 1 updater, with a
    collector and the updater SIGKILLed mid-run: they restart, no collected step is lost uncounted, the limiter holds
    the update-to-data ratio across processes, and the run still reaches the in-process success. (One run
    for both: each alone took about two minutes of a 2-core machine.)"""
    out = tmp_path / "ray"
    killed: dict[str, int] = {}

    def kill_roles():
        deadline = time.monotonic() + 300
        metrics = out / "metrics.csv"
        while time.monotonic() < deadline and not (metrics.exists() and len(read_metrics(metrics)) >= 2):
            time.sleep(0.2)  # mid-run: after the second metrics row
        for name in ("Collector", "BellmanUpdater"):
            pids = _role_pids(name)
            if pids:
                os.kill(pids[0], signal.SIGKILL)
                killed[name] = pids[0]
            time.sleep(1.0)

    killer = threading.Thread(target=kill_roles, daemon=True)
    killer.start()
    run = small_run(
        "pointreach-qtopt-her",
        out,
        distributed=True,
        collectors=2,
        bellman_updaters=1,
        ray_cpus=2,
        actor_cpus=0.5,
        stop_at_success=0.9,
        total_steps=40_000,
        seed=0,
        threads=1,
    )
    killer.join(timeout=5)
    assert set(killed) == {"Collector", "BellmanUpdater"}, killed
    assert run.metrics["success_rate"] >= 0.9
    rows = read_metrics(out / "metrics.csv")
    for row in rows[1:]:
        assert row["updates_per_env_step"] == pytest.approx(0.25, rel=0.05)  # the limiter, across processes
    last = rows[-1]
    assert last["collector_restarts"] == 1 and last["updater_restarts"] == 1  # one kill each, counted once
    assert last["collector0/env_steps_per_s"] > 0 and last["collector1/env_steps_per_s"] > 0
    assert last["updater0/targets_per_s"] > 0 and last["queue_depth"] <= 8  # the restarted updater works
    for row in rows:  # every counted step is stored, counted lost, or in a live collector's running episodes
        unstored = row["env_steps"] - row["lost_env_steps"] - row["replay_transitions"] - row["replay_evicted"]
        assert 0 <= unstored <= run.config.num_envs * 50, row  # at most one running episode per env copy
    stored = [row["stored_episodes"] for row in rows]
    # the trainer resumes from its checkpoint (replay included) with more steps
    resumed = taskrl.train(resume=out, total_steps=run.metrics["env_steps"] + 1_000, stop_at_success=0.0, tensorboard=False)
    assert resumed.metrics["env_steps"] >= run.metrics["env_steps"] + 1_000
    assert read_metrics(out / "metrics.csv")[-1]["stored_episodes"] >= stored[-1]


@pytest.mark.slow
@ON_RAY
def test_dqn_learns_through_ray_collectors_with_its_own_targets(tmp_path):
    # the Ape-X layout on Ray: DQN (epsilon-greedy in each collector) on 8-bit flipping, as in one process
    run = small_run(
        "bitflip-her",
        tmp_path / "dqn",
        n_bits=8,
        total_steps=12_000,
        eval_interval=2_000,
        stop_at_success=0.9,
        seed=0,
        distributed=True,
        collectors=2,
        ray_cpus=2,
    )
    assert run.metrics["success_rate"] >= 0.9
    rows = read_metrics(tmp_path / "dqn" / "metrics.csv")
    for i in (0, 1):  # each collector delivered steps (a row only counts the calls that finished in it)
        assert max(row[f"collector{i}/env_steps_per_s"] for row in rows) > 0, rows


def test_a_collectors_env_and_exploration_draw_from_two_streams():
    """Each life's env seed and exploration seed are two children of one SeedSequence. Mutation: seeding both
    from the collector's seed (the old first life) makes them equal and fails."""
    config = _config(num_envs=2)
    resets = []

    def make_env(seed):
        env = collector_env(config, None, 2, seed)
        reset = env.reset
        env.reset = lambda seed=None, **kwargs: resets.append(seed) or reset(seed=seed, **kwargs)
        return env

    collector = Collector(make_env, lambda env: role_agent(config, env), 10)
    collector.collect(5, -1, lambda: None, 0, 0)
    assert resets and collector.generator.initial_seed() != resets[-1]
    again = Collector(make_env, lambda env: role_agent(config, env), 10)
    again.collect(5, -1, lambda: None, 0, 0)
    assert resets[-1] == resets[0] and again.generator.initial_seed() == collector.generator.initial_seed()  # reproduced
