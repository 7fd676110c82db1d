"""The run modes, by name: how a run of a config runs ([`RunMode`][taskrl.runmodes.spec.RunMode]).

Each mode is declared in its own file; adding one is that file plus one line in `BUILT_IN`, or
`register_run_mode` from a user's code. A config runs in the most recently registered mode that
applies to it, so a more specific mode is registered after a more general one; two modes switched on by
settings (``selected_by``) that both apply are refused in one line naming both settings.
"""

from __future__ import annotations

from taskrl.agents.registry import algorithm
from taskrl.config import TrainConfig
from taskrl.errors import ConfigError
from taskrl.registry import Registry
from taskrl.runmodes import distributed, in_process, offline
from taskrl.runmodes.spec import RunMode

__all__ = ["RUN_MODES", "progress_axis", "register_run_mode", "run_mode"]

#: general first: a later mode that applies wins over an earlier one.
BUILT_IN: tuple[RunMode, ...] = (
    in_process.OFF_POLICY,
    in_process.ON_POLICY,
    offline.DATASET,
    offline.STORED_DATA,
    distributed.DISTRIBUTED,
)

RUN_MODES: Registry[RunMode] = Registry("mode", BUILT_IN, hint=", or auto")


def register_run_mode(mode: RunMode, replace: bool = False) -> RunMode:
    """Make ``mode`` available; configs it ``applies`` to run in it from now on."""
    return RUN_MODES.register(mode, replace)


def run_mode(config: TrainConfig) -> RunMode:
    """The mode ``config`` runs in: ``config.mode`` when named, else the most recently registered mode that applies.

    A `ConfigError` on ``mode`` when a named mode does not apply to the config, on ``algo`` when the mode does not run
    its algorithm, and on the first setting when two settings switch on two modes."""
    loop = algorithm(config.algo).loop
    applying = [mode for mode in reversed(list(RUN_MODES.values())) if mode.applies(config)]
    switched = [mode for mode in applying if mode.selected_by]
    if len(switched) > 1:  # two switches asking for two modes: never one of them silently
        first, second = switched[:2]
        raise ConfigError(
            first.selected_by,
            f"--{first.selected_by.replace('_', '-')} selects the {first.name} run mode and "
            f"--{second.selected_by.replace('_', '-')} the {second.name} one; a run has one mode: drop one of them",
        )
    if config.mode != "auto":
        named = RUN_MODES.lookup(config.mode)
        if named not in applying:
            switch = f" (switched on by --{named.selected_by.replace('_', '-')})" if named.selected_by else ""
            derived = f"; the settings given select {applying[0].name}" if applying else ""
            raise ConfigError(
                "mode", f"names the {named.name} run mode{switch}, which does not run this config{derived}; use auto"
            )
        applying = [named]
    if applying:
        mode = applying[0]
        if loop not in mode.loops:
            raise ConfigError(
                "algo",
                f"{config.algo} learns {loop.replace('_', '-')}; the {mode.name} run mode runs {', '.join(mode.loops)} algorithms",
            )
        return mode
    raise ConfigError("algo", f"no run mode runs {config.algo} ({loop}); registered: {', '.join(RUN_MODES)}")


def progress_axis(config: TrainConfig) -> str:
    """What a run's ``total_steps`` counts: ``env_steps``, or ``updates`` for a run that steps no env."""
    return run_mode(config).axis
