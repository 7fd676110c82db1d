"""Whether an algorithm fits a run: the env's actions, camera and tasks, and what the run's settings ask of it
(a replay to relabel or to preload, compiled updates). Checked before building (with what the env family
declares) and again once the env is built (with what it is): the same rules both times."""

from __future__ import annotations

from typing import TYPE_CHECKING

from taskrl.agents.registry import ALGORITHMS, algorithm
from taskrl.config import TrainConfig
from taskrl.errors import ConfigError, require
from taskrl.setting_values import changed_fields

if TYPE_CHECKING:
    from taskrl.agents.spec import AlgorithmSpec

__all__ = ["check_fit", "check_run_needs"]


def check_fit(
    config: TrainConfig,
    kind: str | None,
    actions: str | None,
    images: bool = False,
    env_label: str = "",
    spec: AlgorithmSpec | None = None,
) -> None:
    """The rules between the env (its ``kind``: ``goal``, ``multitask``, ``plain`` or None when unknown; its
    ``actions``: ``discrete`` or ``box``; whether it has a camera) and the algorithm (``spec``, default looked up
    by ``config.algo``), in one `ConfigError` line."""
    c, spec = config, spec or algorithm(config.algo)
    name = env_label or c.env
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
    if c.replay.her != "none":
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
        changed = changed_fields(c.conditioning)
        require(
            not changed,
            next(iter(changed), "task_encoder"),
            f"applies to multi-task envs only (observations with a task index); {name!r} has no tasks",
        )
    if c.replay.sampling == "task_balanced":
        require(
            kind in (None, "multitask"),
            "sampling",
            f"task_balanced needs a multi-task env (observations with a task index); {name!r} is not one",
        )


def check_run_needs(config: TrainConfig) -> None:
    """What the run's settings ask of the algorithm: a replay (relabelling, preloading, sharing, the switched
    modes), compiled updates, several updates per call."""
    c, spec = config, algorithm(config.algo)
    replay_settings = {
        "recent_fraction": c.replay.recent_fraction > 0,
        "offline_data": bool(c.data.offline_data),
        "offline_updates": c.data.offline_updates > 0,
        "scripted_exploration": c.data.scripted_exploration > 0,
        "distributed": c.cluster.distributed,
        "offline": c.data.offline,
        "sharing": c.data_sharing.sharing != "none",
    }
    for name, used in replay_settings.items():
        require(
            not used or spec.loop == "off_policy",
            name,
            f"needs an off-policy algorithm with a replay (allowed: {', '.join(a.name for a in ALGORITHMS.values() if a.loop == 'off_policy')})",
        )
    compiling = ", ".join(a.name for a in ALGORITHMS.values() if a.compiles)
    if c.compile not in ("off", "auto"):
        require(spec.compiles, "compile", f"compiles the updates of {compiling}, not {c.algo}; use --compile off or auto")
    if c.updates_per_call > 1:
        require(
            spec.compiles and spec.loop == "off_policy",
            "updates_per_call",
            f"applies to the off-policy updates of {compiling}, not {c.algo}; use 1",
        )
        require(
            not c.cluster.distributed and not c.data.offline,
            "updates_per_call",
            "applies to the off-policy loop in one process (not --distributed or --offline); use 1",
        )
    if spec.loop == "off_policy":
        require(
            c.replay.buffer_size >= c.batch_size,
            "buffer_size",
            f"must hold at least one batch (batch_size={c.batch_size}; got {c.replay.buffer_size})",
        )
