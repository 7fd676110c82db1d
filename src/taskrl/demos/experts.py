"""Where demonstrations come from: an env family that declares a scripted expert for its tasks
([`demos`][taskrl.envs.spec.EnvFamily.demos], a [`DemoSource`][taskrl.envs.spec.DemoSource]).

``taskrl demos collect SOURCE`` names the family, or some of its tasks:

- ``mt10``, ``mt50``: Meta-World's task sets, each task's scripted v3 expert from
  ``metaworld.policies`` (``ENV_POLICY_MAP``), goal positions resampled every episode;
- ``ml45``: all 50 tasks, with Meta-World's ML45 split (45 training, 5 test tasks) in the card, so one
  dataset serves training and one-demonstration prompts of the held-out tasks;
- ``FAMILY:task,task`` (``mt50:reach,push``), or a bare comma-separated list of Meta-World task names;
- ``pointreach-mt``: the native multi-task point reaching tasks, with the optimal controller
  (straight to the region at full speed, then stay).

A source says when a demonstration counts: Meta-World episodes end ``after_success`` steps after
their first success (success at any step is Meta-World's protocol; the steps after it show the
expert settling at the goal, which precise tasks such as reach need), PointReach episodes run their
50 steps and count when they end inside the region (its per-task criterion). A new family gets
demonstrations by declaring ``demos`` in its own file.
"""

from __future__ import annotations

import dataclasses

from taskrl.envs.registry import ENV_FAMILIES
from taskrl.envs.spec import DemoSource, Expert
from taskrl.errors import ConfigError

__all__ = ["DemoSource", "Expert", "demo_source", "demo_sources"]

#: the family whose tasks a bare comma-separated list names (``reach,push``)
TASK_LIST_FAMILY = "mt50"


def demo_sources() -> list[str]:
    """The families that declare a scripted expert, by name."""
    return [name for name, family in ENV_FAMILIES.items() if family.demos is not None]


def demo_source(name: str) -> DemoSource:
    """The source ``taskrl demos collect`` names: a family with a scripted expert, ``FAMILY:task,task``, or a
    comma-separated list of Meta-World tasks; a `ConfigError` on ``source`` otherwise."""
    allowed = f"{', '.join(demo_sources())}, FAMILY:task,task or Meta-World task names separated by commas"
    if not isinstance(name, str) or not name.strip():
        raise ConfigError("source", f"expected one of {allowed}")
    key = name.strip().lower()
    family_name, _, tasks = key.partition(":") if ":" in key else (key, "", "")
    if family_name not in ENV_FAMILIES or ":" not in key and "," in key:
        family_name, tasks = TASK_LIST_FAMILY, key
    family = ENV_FAMILIES.get(family_name)
    if family is None or family.demos is None:
        raise ConfigError("source", f"{family_name!r} has no scripted expert; allowed: {allowed}")
    names = [n.strip() for n in tasks.split(",") if n.strip()] or None
    if ":" in key and names is None:
        raise ConfigError("source", f"{family_name}: names no task; give {family_name}:task,task or {family_name} for all")
    try:
        return dataclasses.replace(family.demos(names), name=key)
    except ValueError as error:
        raise ConfigError("source", f"{error}; or a source: {allowed}") from None
