"""The algorithms a run can use, by name: one :class:`~taskrl.agents.spec.AlgorithmSpec` each.

Each algorithm's file declares its ``SPEC``; adding one is that file plus one line in
:data:`BUILT_IN`. A user's own algorithm enters through :func:`register_algorithm`.
"""

from __future__ import annotations

from taskrl.agents import dqn, ppo, qtopt, sac, td3
from taskrl.agents.spec import AlgorithmSpec
from taskrl.errors import ConfigError

__all__ = ["ALGORITHMS", "algorithm", "register_algorithm"]

BUILT_IN: tuple[AlgorithmSpec, ...] = (dqn.SPEC, qtopt.SPEC, sac.SPEC, td3.SPEC, ppo.SPEC)

#: name -> spec, in registration order.
ALGORITHMS: dict[str, AlgorithmSpec] = {spec.name: spec for spec in BUILT_IN}


def register_algorithm(spec: AlgorithmSpec, replace: bool = False) -> AlgorithmSpec:
    """Make ``spec`` available as ``--algo spec.name`` and ``taskrl.train(..., algo=spec.name)``."""
    if spec.name in ALGORITHMS and not replace:
        raise ValueError(f"an algorithm named {spec.name!r} is already registered (pass replace=True)")
    ALGORITHMS[spec.name] = spec
    return spec


def algorithm(name: str) -> AlgorithmSpec:
    """The spec of ``name``; a :class:`ConfigError` on ``algo`` listing the registered names otherwise."""
    if name not in ALGORITHMS:
        raise ConfigError("algo", f"unknown algo {name!r}; allowed: {', '.join(ALGORITHMS)}")
    return ALGORITHMS[name]
