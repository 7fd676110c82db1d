"""A run resolved once: `resolve(config) -> RunPlan` looks up the env family, the algorithm, the run mode and
the sharing strategy, and has each check its own fit; later stages read the plan.

`validate` is the same checks, returning the config. Run-level settings are checked here, each section
by its own ``validate()``, env against algorithm by [`check_fit`][taskrl.fit.check_fit], what the
settings ask of the algorithm by [`check_run_needs`][taskrl.fit.check_run_needs], each run mode's
and sharing strategy's needs by their own ``check``, and the family's rules by ``family.check``.
"""

from __future__ import annotations

import dataclasses

from taskrl.agents.compiled import RUN_COMPILE_MODES
from taskrl.agents.registry import ALGORITHMS, algorithm
from taskrl.agents.spec import AlgorithmSpec
from taskrl.config import TrainConfig
from taskrl.envs.registry import ENV_FAMILIES, env_family, env_label
from taskrl.envs.spec import EnvFamily
from taskrl.errors import one_of, require
from taskrl.fit import check_fit, check_run_needs
from taskrl.runmodes.registry import run_mode
from taskrl.runmodes.spec import RunMode
from taskrl.setting_values import check_device
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.strategy import SharingStrategy

__all__ = ["HER_STRATEGIES", "SAMPLINGS", "RunPlan", "resolve", "validate"]

SAMPLINGS = ("uniform", "task_balanced")
HER_STRATEGIES = ("future", "final", "episode", "random", "none")


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A config and the registered pieces it runs with, each looked up once.

    Attributes:
        config: the validated settings.
        family: the env family (``config.env``).
        algorithm: the algorithm (``config.algo``).
        mode: the run mode (how the run runs: one process, distributed, offline).
        sharing: the data-sharing strategy (``none`` shares nothing).
    """

    config: TrainConfig
    family: EnvFamily
    algorithm: AlgorithmSpec
    mode: RunMode
    sharing: SharingStrategy


def _check_run_level(c: TrainConfig) -> None:
    """The run-level settings' own ranges and values."""
    one_of(c.her, HER_STRATEGIES, "her", "strategy")
    one_of(c.sampling, SAMPLINGS, "sampling", "sampling")
    for name in ("total_steps", "num_envs", "batch_size", "eval_interval", "eval_episodes", "checkpoint_interval"):
        require(getattr(c, name) >= 1, name, f"must be >= 1 (got {getattr(c, name)})")
    for name in ("her_k", "learning_starts", "updates_per_step", "threads", "tensorboard_interval", "offline_updates"):
        require(getattr(c, name) >= 0, name, f"must be >= 0 (got {getattr(c, name)})")
    require(c.max_hours >= 0, "max_hours", f"must be >= 0 hours (0 = no limit; got {c.max_hours})")
    require(0.0 <= c.stop_at_success <= 1.0, "stop_at_success", f"must be in [0, 1] (got {c.stop_at_success})")
    check_device(c.device)
    one_of(c.compile, RUN_COMPILE_MODES, "compile", "mode")
    require(c.updates_per_call >= 0, "updates_per_call", f"must be >= 1, or auto (0; got {c.updates_per_call})")
    require(c.checkpoint_minutes >= 0, "checkpoint_minutes", f"must be >= 0 (0 = by env steps only; got {c.checkpoint_minutes})")
    require(0.0 <= c.recent_fraction <= 1.0, "recent_fraction", f"must be in [0, 1] (got {c.recent_fraction})")
    require(c.recent_episodes >= 1, "recent_episodes", f"must be >= 1 (got {c.recent_episodes})")
    require(0.0 <= c.scripted_exploration <= 1.0, "scripted_exploration", f"must be in [0, 1] (got {c.scripted_exploration})")
    require(c.scripted_steps >= 0, "scripted_steps", f"must be >= 0 env steps (0: the whole run; got {c.scripted_steps})")
    require(
        c.offline_updates == 0 or bool(c.offline_data),
        "offline_updates",
        "updates before collection need data to learn from: --offline-data RUN_DIR",
    )


def resolve(config: TrainConfig) -> RunPlan:
    """The plan of ``config``: its pieces looked up once, and every rule between them checked; a `ConfigError`
    naming the setting and the allowed values otherwise."""
    c = config
    family, spec = env_family(c.env), algorithm(c.algo)
    strategy = sharing_strategy(c.data_sharing.sharing)
    _check_run_level(c)
    c.conditioning.validate()
    c.cluster.validate()
    c.data_sharing.validate()
    check_run_needs(c)
    label = env_label(c.env, c.env_settings)
    strategy.check(
        c.sampling,
        family,
        spec,
        label,
        rewarded_envs=", ".join(f.name for f in ENV_FAMILIES.values() if f.task_rewards),
        ranked_algos=", ".join(a.name for a in ALGORITHMS.values() if a.q_values),
    )
    mode = run_mode(c)
    if mode.check is not None:
        mode.check(c)
    c.env_settings.validate()
    c.algo_settings.validate()
    check_fit(c, family.kind, family.actions, family.images, label)
    require(
        c.scripted_exploration == 0 or family.scripted is not False,
        "scripted_exploration",
        f"{c.env!r} has no scripted policy (families with one: {', '.join(f.name for f in ENV_FAMILIES.values() if f.scripted)})",
    )
    if family.check is not None:
        family.check(c.env_settings, c)
    return RunPlan(c, family, spec, mode, strategy)


def validate(config: TrainConfig) -> TrainConfig:
    """``config`` once `resolve` has checked it; a `ConfigError` naming the setting and the allowed values otherwise."""
    return resolve(config).config
