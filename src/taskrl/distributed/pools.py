"""A group of role objects the trainer calls asynchronously: `LocalPool` runs them in this
process (each call at once), `LatePool` also returns them late and out of order,
[`RayPool`][taskrl.distributed.actors.RayPool] as Ray actors. The loop speaks only this interface, so it reads
the same either way and is tested without Ray."""

from __future__ import annotations

import copy
import random
from collections.abc import Callable, Sequence
from typing import Any, Protocol

__all__ = ["LatePool", "LocalPool", "Pool", "RoleCannotStart", "RoleDied"]


class RoleDied(RuntimeError):
    """The process of a role died during a call (it restarts if restarts are left)."""


class RoleRestarting(RoleDied):
    """A call failed because the role's process is being restarted: the one that died with it in hand, or
    one sent since, before the new process is up. The death it shows may be one already counted."""


class RoleCannotStart(RuntimeError):
    """A role's constructor raised (an env or module its process cannot build or import) or it never
    started: no restart helps, so the run stops with the reason."""


class Pool(Protocol):
    """Roles ``0 .. size - 1`` of one kind."""

    size: int

    def wait_started(self, timeout: float) -> None:
        """Wait up to ``timeout`` s until every role is constructed; `RoleCannotStart` if one cannot be."""

    def submit(self, index: int, method: str, *args: Any) -> Any:
        """Start ``role[index].method(*args)``; a handle to its result."""

    def ready(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        """Those of ``handles`` whose calls have finished, waiting up to ``timeout`` s for at least one."""

    def result(self, handle: Any) -> Any:
        """The call's return value; `RoleDied` if its process died."""

    def publish(self, value: Any) -> Callable[[], Any]:
        """``fetch() -> value`` for roles to pull a published object (weights) when they need it."""

    def call_all(self, method: str, timeout: float) -> list[Any]:
        """``method()`` of every live role, waiting up to ``timeout`` s; the results that came back."""

    def close(self) -> None:
        """Stop the roles."""


class _Done:
    def __init__(self, value: Any = None, error: BaseException | None = None) -> None:
        self.value, self.error = value, error


class LocalPool:
    """Role objects in this process; ``submit`` runs the call before returning.

    Args:
        roles: the role objects (e.g. [`Collector`][taskrl.distributed.roles.Collector]).
    """

    def __init__(self, roles: Sequence[Any]) -> None:
        self.roles, self.size = list(roles), len(roles)

    def wait_started(self, timeout: float) -> None:
        pass  # constructed in this process already

    def submit(self, index: int, method: str, *args: Any) -> _Done:
        try:
            return _Done(getattr(self.roles[index], method)(*args))
        except RoleDied as error:
            return _Done(error=error)

    def ready(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        return list(handles)

    def result(self, handle: _Done) -> Any:
        if handle.error is not None:
            raise handle.error
        return handle.value

    def publish(self, value: Any) -> Callable[[], Any]:
        snapshot = copy.deepcopy(value)  # as Ray's object store: the trainer's later updates do not show through
        return lambda: snapshot

    def call_all(self, method: str, timeout: float) -> list[Any]:
        return [getattr(role, method)() for role in self.roles]

    def close(self) -> None:
        for role in self.roles:
            close = getattr(role, "close", None)
            if close is not None:
                close()


class LatePool(LocalPool):
    """A `LocalPool` whose calls finish late and out of order, as on Ray: each call runs when it is
    submitted (with the weights of that moment) but shows as finished only after 0 to ``max_polls`` looks of
    `ready`, drawn at random, and those finished together come back shuffled.

    Args:
        roles: the role objects.
        max_polls: the most looks at ``ready`` a call stays unfinished for.
        seed: seed of the draws.
    """

    def __init__(self, roles: Sequence[Any], max_polls: int = 4, seed: int = 0) -> None:
        super().__init__(roles)
        self.max_polls, self.random = max_polls, random.Random(seed)
        self.polls_left: dict[int, int] = {}

    def submit(self, index: int, method: str, *args: Any) -> _Done:
        handle = super().submit(index, method, *args)
        self.polls_left[id(handle)] = self.random.randint(0, self.max_polls)
        return handle

    def ready(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        done = []
        for handle in handles:
            left = self.polls_left.get(id(handle), 0)
            if left <= 0:
                done.append(handle)
            else:
                self.polls_left[id(handle)] = left - 1
        self.random.shuffle(done)
        return done

    def result(self, handle: _Done) -> Any:
        self.polls_left.pop(id(handle), None)
        return super().result(handle)
