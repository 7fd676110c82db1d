"""The algorithms a run can use, by name: one [`AlgorithmSpec`][taskrl.agents.spec.AlgorithmSpec] each.

Each algorithm's file declares its ``SPEC``; adding one is that file plus one line in
`BUILT_IN`. A user's own algorithm enters through `register_algorithm`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from taskrl.registry import Declared, Registry

if TYPE_CHECKING:
    from taskrl.agents.spec import AlgorithmSpec

__all__ = ["ALGORITHMS", "algorithm", "register_algorithm"]

# each algorithm's file declares its SPEC; it is imported when a run (or --help) first names it
BUILT_IN: tuple[Declared, ...] = tuple(
    Declared(name, f"taskrl.agents.{module}", "SPEC")
    for name, module in (("dqn", "dqn"), ("qtopt", "qtopt"), ("sac", "sac"), ("td3", "td3"), ("ppo", "ppo"), ("bc", "bc"))
)

#: name -> spec, in registration order.
ALGORITHMS: Registry[AlgorithmSpec] = Registry("algo", BUILT_IN)


def register_algorithm(spec: AlgorithmSpec, replace: bool = False) -> AlgorithmSpec:
    """Make ``spec`` available as ``--algo spec.name`` and ``taskrl.train(..., algo=spec.name)``."""
    return ALGORITHMS.register(spec, replace)


def algorithm(name: str) -> AlgorithmSpec:
    """The spec of ``name``; a `ConfigError` on ``algo`` listing the registered names otherwise."""
    return ALGORITHMS.lookup(name)
