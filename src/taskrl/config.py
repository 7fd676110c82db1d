"""Typed run configuration: run-level settings plus one section for the env family and one for the
algorithm, each validated by its own ``validate()``, saved with every run.

``config.json`` reads::

    {"env": "bitflip", "algo": "dqn", "total_steps": 60000, ..., "conditioning": {...},
     "bitflip": {"n_bits": 15, ...}, "dqn": {"lr": 0.001, "epsilon_start": 0.5, ...}}

The sections are those of the registries (``taskrl.envs.registry``, ``taskrl.agents.registry``):
a new family or algorithm brings its own. The CLI turns every run-level field and every field of
the active sections into a flat ``--kebab-case`` flag (``--lr`` is the active algorithm's learning
rate, ``--n-bits`` the bit-flipping section's length).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import typing
from pathlib import Path
from typing import Any, Literal

from taskrl.agents.compiled import RUN_COMPILE_MODES
from taskrl.agents.registry import ALGORITHMS, algorithm
from taskrl.conditioning.networks import ConditioningConfig
from taskrl.distributed.settings import DistributedConfig
from taskrl.envs.registry import ENV_FAMILIES, env_family
from taskrl.errors import ConfigError, one_of, reason, require
from taskrl.rundir import atomic_write_text
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.settings import SharingConfig

__all__ = [
    "ConfigError",
    "HER_STRATEGIES",
    "SAMPLINGS",
    "TrainConfig",
    "check_fit",
    "field_help",
    "setting_help",
    "setting_names",
    "from_dict",
    "leaf_fields",
    "load",
    "save",
    "to_dict",
    "validate",
    "with_overrides",
]

SAMPLINGS = ("uniform", "task_balanced")
HER_STRATEGIES = ("future", "final", "episode", "random", "none")
#: Algorithm settings that carry over when ``algo`` changes (if the old section changed them).
SHARED_ALGO_SETTINGS = ("lr", "gamma", "hidden_sizes", "tau", "max_grad_norm", "normalize_inputs", "clip_target")
_SECTIONS = ("env_settings", "algo_settings")


@dataclasses.dataclass
class TrainConfig:
    """Everything a training run needs; saved as ``config.json`` in the run directory.

    Attributes:
        env: environment family (``taskrl train --help`` lists them; ``gym`` is any gymnasium id
            given by ``--env-id``, ``tasks`` a task set given by ``--task-file``). Its settings are
            the section named after it (``bitflip.n_bits``, ``metaworld.task``, ...).
        algo: learning algorithm; its section (``dqn``, ``qtopt``, ``sac``, ``td3``, ``ppo``) holds its
            hyperparameters and its exploration. ``ppo`` (also REINFORCE, via its ``estimator``) learns
            on-policy: the replay, relabelling, batch and update-ratio settings do not apply to it.
        total_steps: environment steps to train for (summed over parallel environments).
        num_envs: environments stepped in parallel while collecting.
        seed: seed for network initialisation, environments and sampling.
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA when available).
        buffer_size: replay capacity in transitions.
        her: hindsight strategy (``none`` disables relabelling).
        her_k: relabelled transitions per real one; the relabelled fraction is k/(k+1).
        batch_size: transitions per gradient update.
        learning_starts: environment steps collected before the first update.
        updates_per_step: gradient updates per environment step (fractions accumulate).
        updates_per_call: gradient updates made in one call of the agent, each on its own batch
            (compiled, one graph for all of them: less overhead per update at high update
            ratios); updates wait until that many are due. 1 = one at a time; 0 (``auto`` on the command
            line) = 4 where that is estimated faster with ``compile``, else 1.
        sampling: ``uniform`` over stored transitions, or ``task_balanced`` (multi-task envs: the
            same number of transitions of every task in each batch).
        eval_interval: environment steps between evaluations.
        eval_episodes: episodes per evaluation (greedy policy, fixed evaluation seeds); on
            multi-task envs, episodes per task (Meta-World: over distinct goal positions, at most 50).
        stop_at_success: stop once evaluation success reaches this (0 = train to total_steps).
        checkpoint_interval: environment steps between checkpoints (also one after the first step
            and one at the end).
        checkpoint_minutes: also checkpoint after this many minutes of wall-clock since the last
            checkpoint, so a killed run loses at most that much (0 = by env steps only).
        tensorboard_interval: environment steps between TensorBoard points of the training scalars
            (losses, Q, temperature; ``train/...``) between evaluations (0: at evaluations only).
        save_replay: include the replay buffer in checkpoints so a resumed run loses no data.
        recent_fraction: share of each batch drawn from the most recent ``recent_episodes`` episodes
            (QT-Opt's on-policy buffer beside its store of all data); 0 = uniform over everything stored.
        recent_episodes: the size of that window, in episodes.
        offline_data: a run directory whose last checkpoint's replay preloads this run's replay
            (QT-Opt's offline data, then online); its env must have the same spaces.
        offline_updates: gradient updates on the preloaded data before collection starts.
        scripted_exploration: share of training episodes acted by the env's scripted policy instead of the
            agent (QT-Opt's first data came from a scripted grasp that succeeded 15-30% of the time); envs with
            one have a ``scripted_action(obs)`` method (``grasp``). 0 = the agent acts in every episode.
        scripted_steps: env steps during which ``scripted_exploration`` applies (0: the whole run).
        offline: learn from stored data only, never stepping an env to collect (the env's
            ``--dataset-quality`` datasets, or ``--offline-data``); ``total_steps``, ``eval_interval`` and
            ``checkpoint_interval`` then count gradient updates; evaluation still runs in the env.
        max_hours: stop cleanly (evaluation, checkpoint) after this many hours of wall-clock in
            this invocation, to continue later with ``--resume``; 0 = no limit. Ctrl-C and
            SIGTERM stop the same way.
        compile: run each gradient update as one ``torch.compile`` graph: ``default``,
            ``reduce-overhead`` (CUDA graphs on GPU) or ``max-autotune``; ``off`` = eager; ``auto`` = compiled
            (``default``) where the run plans enough updates to pay for the compilation, else eager
            (`taskrl.agents.compile_rule`; the run's first note says which and why). Compiling costs seconds
            before the first update (less in a later run: the cache is kept in the user's cache directory); where
            it cannot compile, the run says so on one line and updates eagerly.
        threads: torch CPU threads. 1 by default: the networks here are small, one thread is as
            fast, and torch's multi-threaded kernels stall when another process holds a core
            (measured 100x slower on a busy 2-core machine). 0 = torch's default.
        env_module: a Python module to import before the envs are built (one that registers your
            gymnasium ids). Resuming, evaluating and loading never import it unless you pass it again.
        conditioning: how multi-task networks are told the task (task encoder, architecture).
        cluster: where the roles run: one process, or collectors and Bellman updaters as Ray actors.
        data_sharing: how tasks share data (multi-task envs whose tasks are reward functions).
        env_settings: the env family's section (saved under the family's section name).
        algo_settings: the algorithm's section (saved under the algorithm's name).
    """

    env: str = "bitflip"
    algo: str = "dqn"
    total_steps: int = 100_000
    num_envs: int = 32
    seed: int = 0
    device: str = "cpu"
    buffer_size: int = 1_000_000
    her: Literal["future", "final", "episode", "random", "none"] = "future"
    her_k: int = 4
    batch_size: int = 256
    learning_starts: int = 1_000
    updates_per_step: float = 0.1
    updates_per_call: int = 0
    sampling: Literal["uniform", "task_balanced"] = "uniform"
    eval_interval: int = 5_000
    eval_episodes: int = 100
    stop_at_success: float = 0.0
    checkpoint_interval: int = 50_000
    checkpoint_minutes: float = 10.0
    tensorboard_interval: int = 1_000
    save_replay: bool = True
    recent_fraction: float = 0.0
    recent_episodes: int = 1_000
    offline_data: str = ""
    offline_updates: int = 0
    scripted_exploration: float = 0.0
    scripted_steps: int = 0
    offline: bool = False
    max_hours: float = 0.0
    compile: Literal["auto", "off", "default", "reduce-overhead", "max-autotune"] = "auto"
    threads: int = 1
    env_module: str = ""
    conditioning: ConditioningConfig = dataclasses.field(default_factory=ConditioningConfig)
    cluster: DistributedConfig = dataclasses.field(default_factory=DistributedConfig)
    data_sharing: SharingConfig = dataclasses.field(default_factory=SharingConfig)
    env_settings: Any = None
    algo_settings: Any = None

    def __post_init__(self) -> None:
        if self.env_settings is None:
            self.env_settings = env_family(self.env).settings()
        if self.algo_settings is None:
            self.algo_settings = algorithm(self.algo).config()

    @property
    def env_section(self) -> str:
        """The name the env settings are saved under (families may share one, e.g. ``metaworld``)."""
        return env_family(self.env).section


def _run_fields() -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(TrainConfig) if f.name not in _SECTIONS]


def field_docs(cls: type) -> dict[str, str]:
    """``{field: description}`` from the ``Attributes:`` section of a dataclass docstring."""
    docs: dict[str, str] = {}
    lines = (cls.__doc__ or "").split("Attributes:", 1)[-1].splitlines()
    current: list[str] = []
    for line in lines:
        text = line.strip()
        head, sep, rest = text.partition(":")
        if sep and head and all(part.isidentifier() for part in head.replace(" ", "").split(",")):
            current = [h.strip() for h in head.split(",")]
            for name in current:
                docs[name] = rest.strip()
        elif text and current:
            for name in current:
                docs[name] += " " + text
    return docs


# ---------------------------------------------------------------------- validation
def check_fit(config: TrainConfig, kind: str | None, actions: str | None, images: bool = False) -> None:
    """The rules between the env and the algorithm, checked before building (with what the family
    declares) and again once the env is built (with what it is): the same rules both times."""
    c, spec = config, algorithm(config.algo)
    name = _env_label(c)
    fitting = ", ".join(
        a.name for a in ALGORITHMS.values() if (actions is None or actions in a.actions) and (kind != "multitask" or a.multitask)
    )
    if actions is not None and actions not in spec.actions:
        need = " or ".join("continuous (Box)" if a == "box" else "discrete" for a in spec.actions)
        raise ConfigError("algo", f"{c.algo} needs {need} actions but {name!r} has {actions} actions; allowed: {fitting}")
    if images and not spec.images:
        seeing = ", ".join(a.name for a in ALGORITHMS.values() if a.images and (actions is None or actions in a.actions))
        raise ConfigError("algo", f"{c.algo!r} cannot read the camera pictures of {name!r}; allowed: {seeing}")
    if kind == "multitask" and not spec.multitask:
        raise ConfigError("algo", f"{c.algo!r} does not run on the multi-task env {name!r}; allowed: {fitting}")
    if c.her != "none":
        require(
            spec.loop == "off_policy",
            "her",
            f"{c.algo} learns {'offline from a dataset' if spec.loop == 'offline' else 'on-policy from rollouts'}: there is no replay to relabel; use --her none",
        )
        require(
            kind in (None, "goal"),
            "her",
            f"hindsight relabelling needs a goal env (achieved_goal, desired_goal, compute_reward); "
            f"{name!r} is not one; use --her none",
        )
    if kind in ("goal", "plain"):  # task conditioning set for an env without tasks: say so, do not ignore it
        changed = _changed(c.conditioning)
        require(
            not changed,
            next(iter(changed), "task_encoder"),
            f"applies to multi-task envs only (observations with a task index); {name!r} has no tasks",
        )
    if c.sampling == "task_balanced":
        require(
            kind in (None, "multitask"),
            "sampling",
            f"task_balanced needs a multi-task env (observations with a task index); {name!r} is not one",
        )


def check_roles(config: TrainConfig) -> None:
    """What replay, offline data and distributed roles need of the algorithm."""
    c, spec = config, algorithm(config.algo)
    replay_settings = {
        "recent_fraction": c.recent_fraction > 0,
        "offline_data": bool(c.offline_data),
        "offline_updates": c.offline_updates > 0,
        "scripted_exploration": c.scripted_exploration > 0,
        "distributed": c.cluster.distributed,
        "offline": c.offline,
        "sharing": c.data_sharing.sharing != "none",
    }
    for name, used in replay_settings.items():
        require(
            not used or spec.loop == "off_policy",
            name,
            f"needs an off-policy algorithm with a replay (allowed: {', '.join(a.name for a in ALGORITHMS.values() if a.loop == 'off_policy')})",
        )
    require(0.0 <= c.scripted_exploration <= 1.0, "scripted_exploration", f"must be in [0, 1] (got {c.scripted_exploration})")
    require(c.scripted_steps >= 0, "scripted_steps", f"must be >= 0 env steps (0: the whole run; got {c.scripted_steps})")
    require(
        c.scripted_exploration == 0 or not c.cluster.distributed,
        "scripted_exploration",
        "acts in the one-process loop only (not with --distributed)",
    )
    require(
        c.offline_updates == 0 or bool(c.offline_data),
        "offline_updates",
        "updates before collection need data to learn from: --offline-data RUN_DIR",
    )
    datasets = bool(getattr(c.env_settings, "dataset_quality", ""))
    require(
        not c.offline or bool(c.offline_data) or datasets,
        "offline",
        "learning from stored data only needs data: --offline-data RUN_DIR, or --dataset-quality TASK=QUALITY,...",
    )
    require(
        not (c.offline and c.cluster.distributed),
        "offline",
        "an offline run steps no env: it has no collectors; drop --distributed",
    )
    strategy = sharing_strategy(c.data_sharing.sharing)
    if strategy.shares:  # what the strategy needs, as the family and the algorithm declare it
        family = env_family(c.env)
        rewarded = ", ".join(f.name for f in ENV_FAMILIES.values() if f.task_rewards)
        require(
            family.task_rewards is not False,
            "sharing",
            f"needs an env whose tasks are reward functions (task_reward, task_terminated, task_success); "
            f"{_env_label(c)!r} has none; allowed envs: {rewarded}",
        )
        ranked = ", ".join(a.name for a in ALGORITHMS.values() if a.q_values)
        require(
            not strategy.needs_q_value or spec.q_values,
            "sharing",
            f"{strategy.name} ranks shared data by Q-values; {c.algo} has no q_value; use {ranked}",
        )
    if c.data_sharing.sharing != "none":
        require(
            c.sampling == "task_balanced",
            "sampling",
            "data sharing draws every task's rows of a batch (task-balanced): use --sampling task_balanced",
        )
    if c.cluster.distributed and c.cluster.bellman_updaters > 0:
        splitting = [a.name for a in ALGORITHMS.values() if a.bellman_updaters]
        require(
            spec.bellman_updaters,
            "bellman_updaters",
            f"{c.algo} computes its targets in the trainer (the Ape-X layout): use 0; updaters serve {', '.join(splitting)}",
        )


def _env_label(config: TrainConfig) -> str:
    """What to call the run's env in a message: the gymnasium id or task file that selected its
    family (``my/Slider-v0``), else the family's name."""
    selector = env_family(config.env).selected_by
    return (getattr(config.env_settings, selector, "") if selector else "") or config.env


def check_device(name: str, field: str = "device") -> None:
    """``cpu``, ``cuda``, ``cuda:N`` or ``auto``; anything else is a `ConfigError` on ``field``."""
    require(
        isinstance(name, str) and re.fullmatch(r"cpu|auto|cuda(:\d+)?", name) is not None,
        field,
        f"unknown device {name!r}; allowed: cpu, cuda, cuda:N, auto",
    )


def validate(config: TrainConfig) -> TrainConfig:
    """Raise `ConfigError` naming the field and the allowed values; return the config.

    Run-level settings are checked here, each section by its own ``validate()``, the env family's
    rules between its section and the run by ``family.check``, and env against algorithm by
    `check_fit`.
    """
    c = config
    family = env_family(c.env)
    algorithm(c.algo)
    one_of(c.her, HER_STRATEGIES, "her", "strategy")
    one_of(c.sampling, SAMPLINGS, "sampling", "sampling")
    sharing_strategy(c.data_sharing.sharing)
    for name in ("total_steps", "num_envs", "batch_size", "eval_interval", "eval_episodes", "checkpoint_interval"):
        require(getattr(c, name) >= 1, name, f"must be >= 1 (got {getattr(c, name)})")
    for name in ("her_k", "learning_starts", "updates_per_step", "threads", "tensorboard_interval", "offline_updates"):
        require(getattr(c, name) >= 0, name, f"must be >= 0 (got {getattr(c, name)})")
    require(c.max_hours >= 0, "max_hours", f"must be >= 0 hours (0 = no limit; got {c.max_hours})")
    require(0.0 <= c.stop_at_success <= 1.0, "stop_at_success", f"must be in [0, 1] (got {c.stop_at_success})")
    check_device(c.device)
    one_of(c.compile, RUN_COMPILE_MODES, "compile", "mode")
    compiling = ", ".join(a.name for a in ALGORITHMS.values() if a.compiles)
    if c.compile not in ("off", "auto"):
        require(
            algorithm(c.algo).compiles, "compile", f"compiles the updates of {compiling}, not {c.algo}; use --compile off or auto"
        )
    require(c.updates_per_call >= 0, "updates_per_call", f"must be >= 1, or auto (0; got {c.updates_per_call})")
    if c.updates_per_call > 1:
        require(
            algorithm(c.algo).compiles and algorithm(c.algo).loop == "off_policy",
            "updates_per_call",
            f"applies to the off-policy updates of {compiling}, not {c.algo}; use 1",
        )
        require(
            not c.cluster.distributed and not c.offline,
            "updates_per_call",
            "applies to the off-policy loop in one process (not --distributed or --offline); use 1",
        )
    require(c.checkpoint_minutes >= 0, "checkpoint_minutes", f"must be >= 0 (0 = by env steps only; got {c.checkpoint_minutes})")
    if algorithm(c.algo).loop == "off_policy":
        require(
            c.buffer_size >= c.batch_size,
            "buffer_size",
            f"must hold at least one batch (batch_size={c.batch_size}; got {c.buffer_size})",
        )
    require(0.0 <= c.recent_fraction <= 1.0, "recent_fraction", f"must be in [0, 1] (got {c.recent_fraction})")
    require(c.recent_episodes >= 1, "recent_episodes", f"must be >= 1 (got {c.recent_episodes})")
    c.conditioning.validate()
    c.cluster.validate()
    c.data_sharing.validate()
    check_roles(c)
    c.env_settings.validate()
    c.algo_settings.validate()
    check_fit(c, family.kind, family.actions, family.images)
    scripted = [f.name for f in ENV_FAMILIES.values() if f.scripted]
    require(
        c.scripted_exploration == 0 or family.scripted is not False,
        "scripted_exploration",
        f"{c.env!r} has no scripted policy (families with one: {', '.join(scripted)})",
    )
    if family.check is not None:
        family.check(c.env_settings, c)
    return config


# ---------------------------------------------------------------------- flat settings
Leaf = tuple[tuple[str, ...], dataclasses.Field, type]


def _leaves(cls: type, prefix: tuple[str, ...]) -> list[Leaf]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
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
        if dataclasses.is_dataclass(hints[f.name]):
            out.update(_leaves_with_help(hints[f.name], prefix + (f.name,)))
        else:
            out[prefix + (f.name,)] = docs.get(f.name, "")
    return out


def setting_help(env: str = "bitflip", algo: str = "dqn") -> dict[tuple[str, ...], str]:
    """``{path: description}`` of every setting of a run on ``env`` with ``algo`` (paths as `leaf_fields`)."""
    family = env_family(env)
    return {
        **_leaves_with_help(TrainConfig, ()),
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
            setting keeps its short name whatever a section has.
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
        short = sorted(n for n in self.paths if "." not in n)
        raise ConfigError(name, f"unknown setting for env {env!r} and algo {algo!r}; allowed: {', '.join(short)}")


def setting_names(env: str = "bitflip", algo: str = "dqn") -> SettingNames:
    """The names settings answer to on a run of ``env`` with ``algo``, see `SettingNames`."""
    leaves = [path for path, _, _ in leaf_fields(env, algo)]
    paths: dict[str, tuple[str, ...]] = {}
    by_short: dict[str, list[tuple[str, ...]]] = {}
    for path in leaves:
        paths[dotted_name(path, env, algo)] = path
        if len(path) > 1:
            paths[".".join(path)] = path
        by_short.setdefault(path[-1], []).append(path)
    ambiguous = {}
    for short, owners in by_short.items():
        run_level = [p for p in owners if len(p) == 1]
        if run_level or len(owners) == 1:
            paths[short] = (run_level or owners)[0]
        else:
            ambiguous[short] = [dotted_name(p, env, algo) for p in owners]
    return SettingNames(paths, ambiguous)


def leaf_fields(env: str = "bitflip", algo: str = "dqn") -> list[Leaf]:
    """The settings of a run on ``env`` with ``algo``: ``(path, field, type)`` of every run-level
    field, every field of the conditioning section, of the env family's and of the algorithm's
    section (nested sections flattened). Paths are those of ``config.json``."""
    hints = typing.get_type_hints(TrainConfig)
    top: list[Leaf] = []
    for f in _run_fields():
        tp = hints[f.name]
        top += _leaves(tp, (f.name,)) if dataclasses.is_dataclass(tp) else [((f.name,), f, tp)]
    family = env_family(env)
    return top + _leaves(family.settings, (family.section,)) + _leaves(algorithm(algo).config, (algo,))


def field_help(env: str = "bitflip", algo: str = "dqn") -> dict[str, str]:
    """``{setting: description}`` for the CLI, from the dataclasses' docstrings."""
    docs = field_docs(TrainConfig)
    classes = [ConditioningConfig, DistributedConfig, SharingConfig, env_family(env).settings]
    stack = [algorithm(algo).config]
    while stack:  # the algorithm's section and the sections nested in it (QT-Opt's cem)
        cls = stack.pop()
        classes.append(cls)
        hints = typing.get_type_hints(cls)
        stack += [hints[f.name] for f in dataclasses.fields(cls) if dataclasses.is_dataclass(hints[f.name])]
    for cls in classes:
        docs.update(field_docs(cls))
    return docs


def _changed(section: Any) -> dict[str, Any]:
    """Fields of ``section`` that differ from its class's defaults."""
    default = type(section)()
    return {
        f.name: getattr(section, f.name)
        for f in dataclasses.fields(section)
        if getattr(section, f.name) != getattr(default, f.name)
    }


def _listed(settings: dict[str, Any]) -> str:
    """``lr=0.001, gamma=0.95``."""
    return ", ".join(f"{k}={v}" for k, v in settings.items())


def _lineage(name: str) -> set[str]:
    """The algorithm and the parents it declares (``AlgorithmSpec.parent``)."""
    seen: set[str] = set()
    while name and name not in seen:
        seen.add(name)
        name = algorithm(name).parent or ""
    return seen


def _switch_algorithm(old: Any, old_name: str, new_name: str, notes: list[str]) -> Any:
    """The new algorithm's section, keeping the shared settings the old section had changed."""
    new_cls = algorithm(new_name).config
    new_fields = {f.name for f in dataclasses.fields(new_cls)}
    changed = _changed(old)
    kin = _lineage(old_name) & _lineage(new_name)  # a variant and its parent, or two variants of one parent
    kept = {k: v for k, v in changed.items() if (kin or k in SHARED_ALGO_SETTINGS) and k in new_fields}
    dropped = sorted(set(changed) - set(kept))
    section = new_cls(**kept)
    if kept:
        notes.append(f"--algo {new_name}: kept {_listed(kept)} from {old_name}")
    if dropped:
        notes.append(
            f"--algo {new_name}: {old_name}'s {_listed({k: changed[k] for k in dropped})} "
            f"do{'es' if len(dropped) == 1 else ''} not carry over ({new_name} uses its own defaults)"
        )
    return section


def _selected_family(config: TrainConfig, overrides: dict[str, Any]) -> str:
    if "env" in overrides:
        return overrides["env"]
    for family in ENV_FAMILIES.values():  # --env-id X alone means the gym family, --task-file F the tasks one
        spellings = (family.selected_by, f"env.{family.selected_by}", f"{family.section}.{family.selected_by}")
        if family.selected_by and any(k in overrides for k in spellings) and family.name != config.env:
            current = dataclasses.fields(env_family(config.env).settings)
            if family.selected_by not in {f.name for f in current}:
                return family.name
    return config.env


def with_overrides(config: TrainConfig, overrides: dict[str, Any], notes: list[str] | None = None) -> TrainConfig:
    """A copy of ``config`` with settings replaced by name (``{"n_bits": 30, "lr": 1e-3}``).

    Names are those `setting_names` gives for the resulting ``env`` and ``algo``: in sections
    (``{"algo.lr": 1e-3, "env.n_bits": 30, "algo.cem.samples": 32}``) or short where unambiguous. Changing ``env``
    starts its family's section from defaults (families sharing a section keep it); changing
    ``algo`` keeps the `SHARED_ALGO_SETTINGS` the old section had changed (every setting both sections
    have, between a variant and its ``parent``). What was kept
    or dropped is appended to ``notes``.
    """
    notes = [] if notes is None else notes
    overrides = dict(overrides)
    env = _selected_family(config, overrides)
    algo = overrides.get("algo", config.algo)
    family, old_family = env_family(env), env_family(config.env)
    algorithm(algo)
    env_settings = config.env_settings
    if family.section != old_family.section:
        changed = _changed(config.env_settings)
        if changed:
            notes.append(f"--env {env}: {config.env}'s {_listed(changed)} do{'es' if len(changed) == 1 else ''} not apply")
        env_settings = family.settings()
    conditioning, conditioned = config.conditioning, _changed(config.conditioning)
    if family.kind in ("goal", "plain") and conditioned:  # the preset's task conditioning has no tasks here
        notes.append(f"--env {env}: has no tasks, so the preset's task conditioning ({_listed(conditioned)}) is off")
        conditioning = ConditioningConfig()
    algo_settings, her = config.algo_settings, config.her
    if algo != config.algo:
        algo_settings = _switch_algorithm(config.algo_settings, config.algo, algo, notes)
        if algorithm(algo).loop != "off_policy" and her != "none" and "her" not in overrides:
            how = "offline" if algorithm(algo).loop == "offline" else "on-policy"
            notes.append(f"--algo {algo}: learns {how}, so the preset's hindsight relabelling (her={her}) is off")
            her = "none"
    data = to_dict(
        dataclasses.replace(
            config, env=env, algo=algo, her=her, env_settings=env_settings, algo_settings=algo_settings, conditioning=conditioning
        )
    )
    names = setting_names(env, algo)
    overrides.pop("env", None), overrides.pop("algo", None)
    for name, value in overrides.items():
        node = data
        *parents, leaf = names.resolve(name, env, algo)
        for p in parents:
            node = node[p]
        node[leaf] = list(value) if isinstance(value, tuple) else value
    return from_dict(data)


# ---------------------------------------------------------------------- saving and loading
def to_dict(config: TrainConfig) -> dict[str, Any]:
    """``config.json``'s content: run-level fields, ``conditioning``, and the two sections by name."""
    data = {f.name: getattr(config, f.name) for f in _run_fields()}
    data["conditioning"] = dataclasses.asdict(config.conditioning)
    data["cluster"] = dataclasses.asdict(config.cluster)
    data["data_sharing"] = dataclasses.asdict(config.data_sharing)
    data[config.env_section] = dataclasses.asdict(config.env_settings)
    data[config.algo] = dataclasses.asdict(config.algo_settings)
    return data


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(where.rsplit(".", 1)[-1], f"{where} must be a mapping of settings, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)} - set(_SECTIONS)
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(unknown[0], f"unknown setting in {where}; allowed: {', '.join(sorted(names))}")
    kwargs = {}
    for name, value in data.items():
        tp = hints[name]
        kwargs[name] = _build(tp, value, f"{where}.{name}") if dataclasses.is_dataclass(tp) else checked_value(name, value, tp)
    return cls(**kwargs)


def checked_value(name: str, value: Any, tp: Any) -> Any:
    """``value`` as a setting of type ``tp``, or a `ConfigError` naming ``name`` and what it must be.

    The one type check of every setting, however it arrives (a flag, a keyword of ``taskrl.train``,
    a saved ``config.json``): integers (an integral float such as ``1e6`` is accepted), finite
    numbers, booleans, strings, one of a ``Literal``'s values, lists of positive integers.
    """
    origin = typing.get_origin(tp)
    if tp is bool:
        require(isinstance(value, bool), name, f"must be true or false (got {value!r})")
        return value
    if tp is int:
        integral = isinstance(value, float) and math.isfinite(value) and value.is_integer()
        require(
            (isinstance(value, int) and not isinstance(value, bool)) or integral, name, f"must be a whole number (got {value!r})"
        )
        return int(value)
    if tp is float:
        require(isinstance(value, (int, float)) and not isinstance(value, bool), name, f"must be a number (got {value!r})")
        require(math.isfinite(value), name, f"must be a finite number (got {value!r})")
        return float(value)
    if tp is str:
        require(isinstance(value, str), name, f"must be a string (got {value!r})")
        return value
    if origin is typing.Literal:
        one_of(value, typing.get_args(tp), name, "value")
        return value
    if origin is tuple:
        ok = isinstance(value, (list, tuple)) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        require(ok, name, f"must be a list of whole numbers, e.g. [256, 256] (got {value!r})")
        return tuple(value)
    return value  # a section (checked field by field) or a free-form value


# Settings that sat flat on TrainConfig before the registries (and the section each now lives in).
_LEGACY_ENV_KEYS = ("n_bits", "terminate_on_success", "reward", "vector_strategy", "mt1_task", "max_episode_steps")
_LEGACY_EXPLORATION = ("epsilon_start", "epsilon_end", "epsilon_decay_steps")


def _migrate(data: dict[str, Any]) -> dict[str, Any]:
    """A ``config.json`` written before the registries, in today's shape (flat env settings and a
    loop-level exploration schedule become the sections' own settings; other algorithms' sections go)."""
    if not any(k in data for k in _LEGACY_ENV_KEYS + _LEGACY_EXPLORATION):
        return data
    data = dict(data)
    env, algo = data.get("env", "bitflip"), data.get("algo", "dqn")
    flat = {k: data.pop(k) for k in _LEGACY_ENV_KEYS + _LEGACY_EXPLORATION if k in data}
    family = env_family(env)
    if "mt1_task" in flat:
        flat["task"] = flat.pop("mt1_task")
    fields = {f.name for f in dataclasses.fields(family.settings)}
    data[family.section] = {k: v for k, v in flat.items() if k in fields}
    section = dict(data.get(algo, {}))
    start, end, steps = (flat.get(k) for k in _LEGACY_EXPLORATION)
    if start is not None:
        if algo == "dqn":
            section.update(epsilon_start=start, epsilon_end=end, epsilon_decay_steps=steps)
        elif algo == "qtopt":
            section.update(random_action_prob=start, random_action_prob_end=end, random_action_decay_steps=steps)
        elif algo == "td3":
            section.update(noise_std=end)  # the loop's level was TD3's noise std
    for name in [
        k for k in data if isinstance(data[k], dict) and k not in ("conditioning", "cluster", "data_sharing", family.section)
    ]:
        if name != algo:
            data.pop(name)  # every algorithm's section was saved; only the run's own is kept
    data[algo] = section
    return data


def from_dict(data: dict[str, Any]) -> TrainConfig:
    """Rebuild a config from `to_dict` output (e.g. a run's ``config.json``)."""
    data = _migrate(dict(data))
    env, algo = data.get("env", TrainConfig.env), data.get("algo", TrainConfig.algo)
    family, spec = env_family(env), algorithm(algo)
    sections = {family.section, algo}
    top = {k: v for k, v in data.items() if k not in sections}
    config = _build(TrainConfig, top, "config")
    config.env_settings = _build(family.settings, data.get(family.section, {}), f"config.{family.section}")
    config.algo_settings = _build(spec.config, data.get(algo, {}), f"config.{algo}")
    return config


def save(config: TrainConfig, path: Path) -> None:
    """Write ``config.json`` atomically (temp file, fsync, rename: a kill never leaves half a file)."""
    atomic_write_text(path, json.dumps(to_dict(config), indent=2) + "\n")


def load(path: Path) -> TrainConfig:
    """A saved ``config.json``; any defect (unreadable, not JSON, foreign, wrong types) is one
    `ConfigError` line naming the file or the setting."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise ConfigError("config", f"{path} cannot be read as a taskrl config ({reason(error)})") from None
    if not isinstance(data, dict):
        raise ConfigError("config", f"{path} holds {type(data).__name__}, not a taskrl config (a JSON object)")
    return from_dict(data)
