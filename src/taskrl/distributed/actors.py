"""The Ray shell around the roles: start or join Ray, run role objects as actors, publish weights.

The only module that imports Ray (the ``distributed`` extra); a run without ``--distributed`` never
loads it. Actors take the role's class name, so an operator sees ``ray::Collector`` and
``ray::BellmanUpdater`` in ``ps``; Ray restarts a dead one (``max_restarts``) by re-running its
constructor, and the trainer re-sends its work.
"""

from __future__ import annotations

import logging
import math
import socket
from collections.abc import Callable, Sequence
from typing import Any

from taskrl.distributed.pools import RoleCannotStart, RoleDied, RoleRestarting
from taskrl.distributed.settings import DistributedConfig
from taskrl.errors import ConfigError, reason, require

__all__ = ["RayPool", "start_ray"]


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError("distributed", "needs Ray: pip install 'taskrl[distributed]' (or: pip install 'ray>=2.9')") from None
    return ray


def start_ray(settings: DistributedConfig, actors: int) -> bool:
    """Start a local Ray or join ``ray_address``; whether this call started it (and should shut it down).

    An unreachable address or a cluster that is not there is a `ConfigError` on
    ``ray_address`` (one line, exit 2), never a hang.
    """
    ray = _ray()
    if ray.is_initialized():
        check_capacity(settings, actors)
        return False
    address = settings.ray_address
    quiet = {"include_dashboard": False, "logging_level": logging.ERROR, "log_to_driver": False}
    if not address:
        # "local": a new Ray of this run's own, never the last `ray start` cluster or RAY_ADDRESS as ray.init()
        # with no address would join
        ray.init(address="local", num_cpus=settings.ray_cpus or max(1, math.ceil(actors * settings.actor_cpus)), **quiet)
        _checked(settings, actors)
        return True
    if address == "auto":
        address = _auto_address()
    if address != "auto":
        host, _, port = address.removeprefix("ray://").rpartition(":")
        try:
            socket.create_connection((host, int(port)), timeout=5).close()
        except OSError as error:
            found = (
                ""
                if address == settings.ray_address
                else " (found by 'auto': RAY_ADDRESS, the last `ray start` or a Ray process)"
            )
            raise ConfigError(
                "ray_address",
                f"no Ray cluster answers at {address}{found} ({reason(error)}); start one with `ray start --head` "
                f"or leave --ray-address empty for a local Ray",
            ) from None
    try:
        ray.init(address=address, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as error:
        why = "no running Ray cluster was found" if address == "auto" else reason(error)
        raise ConfigError(
            "ray_address",
            f"cannot join the Ray cluster at {address!r}: {why}; start one with `ray start --head` or leave it empty for a local Ray",
        ) from None
    _checked(settings, actors)
    return False


def _auto_address() -> str:
    """The address ``ray.init(address="auto")`` would join, by Ray's own lookup (``RAY_ADDRESS``, the last
    ``ray start``, then any local process started with a ``--gcs-address``), so that it can be checked first:
    processes left over from a cluster that is gone still name its address, and Ray's core aborts the
    process after 60 s of trying to join it. ``"auto"`` itself where nothing is found or the lookup is not at
    hand: ``ray.init`` then looks itself (and finds no cluster, or finds one its own way)."""
    try:
        from ray._private.services import canonicalize_bootstrap_address
    except ImportError:
        return "auto"
    try:
        return canonicalize_bootstrap_address("auto") or "auto"
    except (ConnectionError, ValueError):
        return "auto"


def check_capacity(settings: DistributedConfig, actors: int) -> None:
    """A `ConfigError` on ``actor_cpus`` when the cluster cannot place every actor (they would
    wait for CPUs forever)."""
    have = _ray().cluster_resources().get("CPU", 0.0)
    need = actors * settings.actor_cpus
    require(
        need <= have + 1e-9,
        "actor_cpus",
        f"{actors} collectors and updaters x {settings.actor_cpus} CPU need {need:g} CPUs; the Ray cluster has {have:g}: "
        f"lower --actor-cpus, raise --ray-cpus, or add nodes",
    )


def _checked(settings: DistributedConfig, actors: int) -> None:
    """`check_capacity` of the Ray this call started or joined (left again when it does not fit)."""
    try:
        check_capacity(settings, actors)
    except ConfigError:
        _ray().shutdown()
        raise


class _Fetch:
    """``fetch()`` of a published object: pulls it from Ray's object store when a role needs it."""

    def __init__(self, ref: Any) -> None:
        self.ref = ref

    def __call__(self) -> Any:
        return _ray().get(self.ref)


def _last_line(error: BaseException) -> str:
    """The last line of a remote error's text: the role's own exception, after Ray's traceback."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return lines[-1][:200] if lines else type(error).__name__


class RayPool:
    """Role objects as Ray actors (one process each).

    Args:
        role: the role's class (its name is the actor's name).
        args: constructor arguments of each actor.
        num_cpus: CPUs each actor reserves in Ray's scheduler.
        max_restarts: Ray restarts of an actor whose process died (-1: unlimited).
    """

    def __init__(self, role: type, args: Sequence[tuple], num_cpus: float, max_restarts: int) -> None:
        ray = _ray()
        self.ray = ray
        remote = ray.remote(role).options(num_cpus=num_cpus, max_restarts=max_restarts, max_task_retries=0)
        self.handles = [remote.remote(*a) for a in args]
        self.size, self.name = len(self.handles), role.__name__

    def wait_started(self, timeout: float) -> None:
        # the first calls then all start together: no role's process start-up counts as collection
        refs = [handle.pid.remote() for handle in self.handles]
        done, _ = self.ray.wait(refs, num_returns=len(refs), timeout=timeout)
        for i, ref in enumerate(refs):
            if ref not in done:
                raise RoleCannotStart(f"{self.name} {i} did not start within {timeout:g} s (is its node gone?)")
            try:
                self.ray.get(ref)
            except self.ray.exceptions.RayError as error:  # its constructor raised, or its exception cannot be unpickled here
                if isinstance(error, self.ray.exceptions.RayActorError) and not error.actor_init_failed:
                    continue  # its process died while starting: Ray restarts it and the loop re-sends its work
                raise RoleCannotStart(f"{self.name} {i} could not start: {_last_line(error)}") from None

    def submit(self, index: int, method: str, *args: Any) -> Any:
        return getattr(self.handles[index], method).remote(*args)

    def ready(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        handles = list(handles)
        if not handles:
            return []
        first, rest = self.ray.wait(handles, num_returns=1, timeout=timeout)
        if not first or not rest:
            return first
        more, _ = self.ray.wait(rest, num_returns=len(rest), timeout=0)
        return first + more

    def result(self, handle: Any) -> Any:
        try:
            return self.ray.get(handle)
        except self.ray.exceptions.RayActorError as error:
            if error.actor_init_failed:  # Ray never restarts a role whose constructor raised
                raise RoleCannotStart(f"a {self.name} could not start: {_last_line(error)}") from None
            if isinstance(error, self.ray.exceptions.ActorUnavailableError) or self._restarting(error):
                raise RoleRestarting(reason(error)) from None
            raise RoleDied(reason(error)) from None

    def _restarting(self, error: Any) -> bool:
        """Whether the actor of a failed call is still Ray's to restart (not DEAD in Ray's actor table): calls
        that reach a dead process before Ray has marked it restarting fail as "died", not "unavailable", and
        must not count as deaths of their own. Where the table cannot be read, the call counts as a death."""
        try:
            return self.ray._private.state.actors(error.actor_id)["State"] != "DEAD"
        except Exception:  # a private table: any failure to read it is "no"
            return False

    def publish(self, value: Any) -> Callable[[], Any]:
        return _Fetch(self.ray.put(value))

    def call_all(self, method: str, timeout: float) -> list[Any]:
        refs = [getattr(h, method).remote() for h in self.handles]
        done, _ = self.ray.wait(refs, num_returns=len(refs), timeout=timeout)
        out = []
        for ref in done:
            try:
                out.append(self.ray.get(ref))
            except self.ray.exceptions.RayError:
                continue  # a role that died on the way out: nothing of it to keep
        return out

    def close(self) -> None:
        for handle in self.handles:
            self.ray.kill(handle)
