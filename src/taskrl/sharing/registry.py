"""The data-sharing strategies, by name (``--sharing``): one [`SharingStrategy`][taskrl.sharing.strategy.SharingStrategy] each.

A new strategy is a file declaring one (its weights, filter or relabelling) and a line in `BUILT_IN`, or
`register_sharing_strategy` from a user's code.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from taskrl.registry import Declared, Registry

if TYPE_CHECKING:
    from taskrl.sharing.strategy import SharingStrategy

__all__ = ["SHARING_STRATEGIES", "register_sharing_strategy", "sharing_strategy"]

# each strategy's file declares it; it is imported when a run (or --help) first names it
BUILT_IN: tuple[Declared, ...] = (
    *(
        Declared(name, "taskrl.sharing.builtin", "BUILT_IN")
        for name in ("none", "all", "random", "success", "hipi", "conservative", "zero-reward")
    ),
    Declared("mtopt", "taskrl.sharing.mtopt", "MTOPT"),
)

#: name -> strategy, in registration order.
SHARING_STRATEGIES: Registry[SharingStrategy] = Registry("sharing", BUILT_IN)


def register_sharing_strategy(strategy: SharingStrategy, replace: bool = False) -> SharingStrategy:
    """Make ``strategy`` available as ``--sharing strategy.name``."""
    return SHARING_STRATEGIES.register(strategy, replace)


def sharing_strategy(name: str) -> SharingStrategy:
    """The strategy called ``name``; a `ConfigError` on ``sharing`` listing them otherwise."""
    return SHARING_STRATEGIES.lookup(name)
