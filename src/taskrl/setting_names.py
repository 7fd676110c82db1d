"""The names a run's settings answer to: every leaf of the run-level fields and of the active env and
algorithm sections, their dotted and short names, and their help from the dataclasses' docstrings."""

from __future__ import annotations

import dataclasses
import typing

from taskrl.agents.registry import algorithm
from taskrl.conditioning.settings import ConditioningConfig
from taskrl.config import TrainConfig, field_docs, run_fields
from taskrl.distributed.settings import DistributedConfig
from taskrl.envs.registry import env_family
from taskrl.errors import ConfigError
from taskrl.run_sections import RUN_SECTIONS
from taskrl.sharing.registry import SHARING_STRATEGIES, sharing_strategy
from taskrl.sharing.settings import SharingConfig

__all__ = [
    "Leaf",
    "SettingNames",
    "dotted_name",
    "field_help",
    "leaf_fields",
    "setting_help",
    "setting_names",
    "strategy_owning",
]

Leaf = tuple[tuple[str, ...], dataclasses.Field, type]
#: fields holding the section of a piece chosen by name: their settings are the chosen piece's (added by name)
_CHOSEN = ("strategy_settings",)


def _strategy_class(sharing: str) -> type | None:
    return sharing_strategy(sharing).settings


def strategy_owning(name: str) -> str | None:
    """The registered sharing strategy whose own settings have a field ``name`` (short or dotted), if one does."""
    short = name.rsplit(".", 1)[-1].replace("-", "_")
    for strategy in SHARING_STRATEGIES.values():
        if strategy.settings is not None and short in {f.name for f in dataclasses.fields(strategy.settings)}:
            return strategy.name
    return None


def _leaves(cls: type, prefix: tuple[str, ...]) -> list[Leaf]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name in _CHOSEN:
            continue
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            out += _leaves(tp, prefix + (f.name,))
        else:
            out.append((prefix + (f.name,), f, tp))
    return out


def _leaves_with_help(cls: type, prefix: tuple[str, ...]) -> dict[tuple[str, ...], str]:
    hints, docs = typing.get_type_hints(cls), field_docs(cls)
    out: dict[tuple[str, ...], str] = {}
    for f in dataclasses.fields(cls):
        if f.name in _CHOSEN:
            continue
        if dataclasses.is_dataclass(hints[f.name]):
            out.update(_leaves_with_help(hints[f.name], prefix + (f.name,)))
        else:
            out[prefix + (f.name,)] = docs.get(f.name, "")
    return out


def setting_help(env: str = "bitflip", algo: str = "dqn", sharing: str = "none") -> dict[tuple[str, ...], str]:
    """``{path: description}`` of every setting of a run on ``env`` with ``algo`` and the ``sharing`` strategy (paths
    as `leaf_fields`)."""
    family, own = env_family(env), _strategy_class(sharing)
    return {
        **_leaves_with_help(TrainConfig, ()),
        **(_leaves_with_help(own, ("data_sharing", sharing)) if own is not None else {}),
        **_leaves_with_help(family.settings, (family.section,)),
        **_leaves_with_help(algorithm(algo).config, (algo,)),
    }


def dotted_name(path: tuple[str, ...], env: str, algo: str) -> str:
    """A setting's name in sections: ``algo.lr``, ``algo.cem.samples``, ``env.n_bits``,
    ``data_sharing.cql_alpha``; a run-level setting is its own name (``total_steps``)."""
    if len(path) == 1:
        return path[0]
    head = "env" if path[0] == env_family(env).section else "algo" if path[0] == algo else path[0]
    return ".".join((head, *path[1:]))


@dataclasses.dataclass(frozen=True)
class SettingNames:
    """What each setting answers to on a run of one env family and algorithm.

    Attributes:
        paths: name -> path in ``config.json``: every dotted name (``algo.lr``; the section's own name
            works too, ``qtopt.lr``) and every short name (``lr``) that is not ambiguous. A run-level
            setting, or one of the run's own sections (`RUN_SECTIONS`: ``replay.sampling``), keeps its short name
            whatever an env or algorithm section has.
        ambiguous: short name -> the dotted names it could mean, for short names two sections share.
    """

    paths: dict[str, tuple[str, ...]]
    ambiguous: dict[str, list[str]]

    def resolve(self, name: str, env: str, algo: str) -> tuple[str, ...]:
        """The path ``name`` means; ``ConfigError`` naming the setting and the allowed names otherwise."""
        if name in self.paths:
            return self.paths[name]
        if name in self.ambiguous:
            raise ConfigError(name, f"is a setting of several sections here: say {' or '.join(self.ambiguous[name])}")
        owner = strategy_owning(name)
        if owner is not None:
            raise ConfigError(name, f"is a setting of the {owner} sharing strategy: choose it with --sharing {owner}")
        short = sorted(n for n in self.paths if "." not in n)
        raise ConfigError(name, f"unknown setting for env {env!r} and algo {algo!r}; allowed: {', '.join(short)}")


def setting_names(env: str = "bitflip", algo: str = "dqn", sharing: str = "none") -> SettingNames:
    """The names settings answer to on a run of ``env`` with ``algo`` and the ``sharing`` strategy, see `SettingNames`."""
    leaves = [path for path, _, _ in leaf_fields(env, algo, sharing)]
    paths: dict[str, tuple[str, ...]] = {}
    by_short: dict[str, list[tuple[str, ...]]] = {}
    for path in leaves:
        paths[dotted_name(path, env, algo)] = path
        if len(path) > 1:
            paths[".".join(path)] = path
        by_short.setdefault(path[-1], []).append(path)
    ambiguous = {}
    for short, owners in by_short.items():
        run_level = [p for p in owners if len(p) == 1 or p[0] in RUN_SECTIONS]  # the run's own settings
        if run_level or len(owners) == 1:
            paths[short] = (run_level or owners)[0]
        else:
            ambiguous[short] = [dotted_name(p, env, algo) for p in owners]
    return SettingNames(paths, ambiguous)


def leaf_fields(env: str = "bitflip", algo: str = "dqn", sharing: str = "none") -> list[Leaf]:
    """The settings of a run on ``env`` with ``algo`` and the ``sharing`` strategy: ``(path, field, type)`` of every
    run-level field, every field of the run's sections, of the sharing strategy's own settings
    (``data_sharing.NAME``), of the env family's and of the algorithm's section (nested sections flattened). Paths are
    those of ``config.json``."""
    hints = typing.get_type_hints(TrainConfig)
    top: list[Leaf] = []
    for f in run_fields():
        tp = hints[f.name]
        top += _leaves(tp, (f.name,)) if dataclasses.is_dataclass(tp) else [((f.name,), f, tp)]
    own = _strategy_class(sharing)
    if own is not None:
        top += _leaves(own, ("data_sharing", sharing))
    family = env_family(env)
    return top + _leaves(family.settings, (family.section,)) + _leaves(algorithm(algo).config, (algo,))


def field_help(env: str = "bitflip", algo: str = "dqn", sharing: str = "none") -> dict[str, str]:
    """``{setting: description}`` for the CLI, from the dataclasses' docstrings."""
    docs = field_docs(TrainConfig)
    classes = [*RUN_SECTIONS.values(), ConditioningConfig, DistributedConfig, SharingConfig, env_family(env).settings]
    own = _strategy_class(sharing)
    if own is not None:
        classes.append(own)
    stack = [algorithm(algo).config]
    while stack:  # the algorithm's section and the sections nested in it (QT-Opt's cem)
        cls = stack.pop()
        classes.append(cls)
        hints = typing.get_type_hints(cls)
        stack += [hints[f.name] for f in dataclasses.fields(cls) if dataclasses.is_dataclass(hints[f.name])]
    for cls in classes:
        docs.update(field_docs(cls))
    return docs
