"""The algorithms a run can use, by name: one [`AlgorithmSpec`][taskrl.agents.spec.AlgorithmSpec] each.

Each algorithm's file declares its ``SPEC``; adding one is that file plus one line in
`BUILT_IN`. A user's own algorithm enters through `register_algorithm`.
"""

from __future__ import annotations

from taskrl.agents import bc, dqn, ppo, qtopt, sac, td3
from taskrl.agents.spec import AlgorithmSpec
from taskrl.registry import Registry

__all__ = ["ALGORITHMS", "algorithm", "register_algorithm"]

BUILT_IN: tuple[AlgorithmSpec, ...] = (dqn.SPEC, qtopt.SPEC, sac.SPEC, td3.SPEC, ppo.SPEC, bc.SPEC)

#: name -> spec, in registration order.
ALGORITHMS: Registry[AlgorithmSpec] = Registry("algo", BUILT_IN)


def register_algorithm(spec: AlgorithmSpec, replace: bool = False) -> AlgorithmSpec:
    """Make ``spec`` available as ``--algo spec.name`` and ``taskrl.train(..., algo=spec.name)``."""
    return ALGORITHMS.register(spec, replace)


def algorithm(name: str) -> AlgorithmSpec:
    """The spec of ``name``; a `ConfigError` on ``algo`` listing the registered names otherwise."""
    return ALGORITHMS.lookup(name)
