"""The environment families a run can use, by name: one [`EnvFamily`][taskrl.envs.spec.EnvFamily] each.

Each family is declared in its environment's own file; adding one is that file plus one line in
`BUILT_IN`. A user's own family enters through `register_env_family`; a user's own
gymnasium environment needs no family at all (``--env-id``, the ``gym`` family).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from taskrl.errors import ConfigError
from taskrl.registry import Declared, Registry

if TYPE_CHECKING:
    from taskrl.envs.spec import EnvFamily

__all__ = ["ENV_FAMILIES", "env_family", "family_for_source", "register_env_family"]


def _declared(module: str, attribute: str, *names: str) -> tuple[Declared, ...]:
    return tuple(Declared(name, f"taskrl.envs.{module}", attribute) for name in names)


# each family's file declares it; it is imported when a run (or --help) first names it
BUILT_IN: tuple[Declared, ...] = (
    *_declared("bitflip", "FAMILY", "bitflip"),
    *_declared("point_reach", "FAMILY", "pointreach"),
    *_declared("pixel_reach", "FAMILY", "pixelreach"),
    *_declared("pixel_push", "FAMILY", "pixelpush"),
    *_declared("fetch", "FAMILIES", "fetchreach", "fetchpush", "fetchpickandplace", "fetchslide"),
    *_declared("multitask_point", "FAMILY", "pointreach-mt"),
    *_declared("tabletop", "FAMILY", "tabletop"),
    *_declared("grid_tasks", "FAMILY", "gridtasks"),
    *_declared("point_tasks", "FAMILY", "pointtasks"),
    *_declared("grasp", "FAMILY", "grasp"),
    *_declared("kuka_grasp", "FAMILY", "kukagrasp"),
    *_declared("meta_world", "FAMILIES", "mt1", "mt10", "mt50", "ml45"),
    *_declared("gymnasium_family", "FAMILY", "gym"),
    *_declared("task_sets", "FAMILY", "tasks"),
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
