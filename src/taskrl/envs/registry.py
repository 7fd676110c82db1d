"""The environment families a run can use, by name: one [`EnvFamily`][taskrl.envs.spec.EnvFamily] each.

Each family is declared in its environment's own file; adding one is that file plus one line in
`BUILT_IN`. A user's own family enters through `register_env_family`; a user's own
gymnasium environment needs no family at all (``--env-id``, the ``gym`` family).
"""

from __future__ import annotations

from typing import Any

from taskrl.envs import (
    bitflip,
    fetch,
    grasp,
    grid_tasks,
    gymnasium_family,
    kuka_grasp,
    meta_world,
    multitask_point,
    pixel_push,
    pixel_reach,
    point_reach,
    point_tasks,
    tabletop,
    task_sets,
)
from taskrl.envs.spec import EnvFamily
from taskrl.errors import ConfigError
from taskrl.registry import Registry

__all__ = ["ENV_FAMILIES", "env_family", "family_for_source", "register_env_family"]

BUILT_IN: tuple[EnvFamily, ...] = (
    bitflip.FAMILY,
    point_reach.FAMILY,
    pixel_reach.FAMILY,
    pixel_push.FAMILY,
    *fetch.FAMILIES,
    multitask_point.FAMILY,
    tabletop.FAMILY,
    grid_tasks.FAMILY,
    point_tasks.FAMILY,
    grasp.FAMILY,
    kuka_grasp.FAMILY,
    *meta_world.FAMILIES,
    gymnasium_family.FAMILY,
    task_sets.FAMILY,
)

#: name -> family, in registration order.
ENV_FAMILIES: Registry[EnvFamily] = Registry("env", BUILT_IN, hint=" (or any gymnasium id with --env-id)")


def register_env_family(family: EnvFamily, replace: bool = False) -> EnvFamily:
    """Make ``family`` available as ``--env family.name``."""
    return ENV_FAMILIES.register(family, replace)


def env_family(name: str) -> EnvFamily:
    """The family called ``name``; a `ConfigError` on ``env`` listing the registered ones otherwise."""
    return ENV_FAMILIES.lookup(name)


def family_for_source(obj: Any) -> EnvFamily:
    """The family that builds envs from the Python object ``obj`` (a TaskSet, a factory)."""
    for family in ENV_FAMILIES.values():
        if family.accepts is not None and family.accepts(obj):
            return family
    raise ConfigError(
        "env", f"cannot train on {obj!r}: pass an env family name, a gymnasium id, a factory of a gymnasium.Env, or a TaskSet"
    )


def env_label(name: str, settings: Any) -> str:
    """What to call a run's env in a message: the gymnasium id or task file that selected its family
    (``my/Slider-v0``, read from ``settings``), else the family's ``name``."""
    selector = env_family(name).selected_by
    return (getattr(settings, selector, "") if selector else "") or name
