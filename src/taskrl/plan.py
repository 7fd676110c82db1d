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
from taskrl.run_sections import HER_STRATEGIES, SAMPLINGS
from taskrl.runmodes.registry import run_mode
from taskrl.runmodes.spec import RunMode
from taskrl.setting_values import check_device
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.strategy import SharingStrategy

__all__ = ["HER_STRATEGIES", "SAMPLINGS", "RunPlan", "resolve", "validate"]


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
    """The run-level settings' own ranges and values, then each of the run's sections'."""
    for name in ("total_steps", "num_envs", "batch_size"):
        require(getattr(c, name) >= 1, name, f"must be >= 1 (got {getattr(c, name)})")
    for name in ("learning_starts", "updates_per_step", "threads", "tensorboard_interval"):
        require(getattr(c, name) >= 0, name, f"must be >= 0 (got {getattr(c, name)})")
    require(c.max_hours >= 0, "max_hours", f"must be >= 0 hours (0 = no limit; got {c.max_hours})")
    check_device(c.device)
    one_of(c.compile, RUN_COMPILE_MODES, "compile", "mode")
    require(c.updates_per_call >= 0, "updates_per_call", f"must be >= 1, or auto (0; got {c.updates_per_call})")
    for section in (c.replay, c.evaluation, c.checkpoints, c.data, c.conditioning, c.cluster, c.data_sharing):
        section.validate()


def resolve(config: TrainConfig) -> RunPlan:
    """The plan of ``config``: its pieces looked up once, and every rule between them checked; a `ConfigError`
    naming the setting and the allowed values otherwise."""
    c = config
    family, spec = env_family(c.env), algorithm(c.algo)
    strategy = sharing_strategy(c.data_sharing.sharing)
    _check_run_level(c)
    check_run_needs(c)
    label = env_label(c.env, c.env_settings)
    strategy.check(
        c.replay.sampling,
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
    check_fit(c, family.kind, family.actions, family.images, label, spec=spec)
    require(
        c.data.scripted_exploration == 0 or family.scripted is not False,
        "scripted_exploration",
        f"{c.env!r} has no scripted policy (families with one: {', '.join(f.name for f in ENV_FAMILIES.values() if f.scripted)})",
    )
    if family.check is not None:
        family.check(c.env_settings, c)
    return RunPlan(c, family, spec, mode, strategy)


def validate(config: TrainConfig) -> TrainConfig:
    """``config`` once `resolve` has checked it; a `ConfigError` naming the setting and the allowed values otherwise."""
    return resolve(config).config
