"""What a run mode declares: how a run of a config runs, and what that asks of its parts."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

from taskrl.config import TrainConfig
from taskrl.envs.base import BatchedEnv

if TYPE_CHECKING:  # annotations only: the wiring layer imports this module
    from taskrl.training.bookkeeping import Bookkeeping
    from taskrl.wiring.parts import RunParts

__all__ = ["RunMode", "steps_and_last_of_each_copy"]


def steps_and_last_of_each_copy(config: TrainConfig, env: BatchedEnv) -> int:
    """The env steps a run in one process stores: ``total_steps``, and the last step of every copy past it."""
    return config.total_steps + env.num_envs


@dataclasses.dataclass(frozen=True)
class RunMode:
    """How a run runs: which loop drives it and what it asks of its envs, replay and process.

    Register one with [`taskrl.runmodes.registry.register_run_mode`][taskrl.runmodes.registry.register_run_mode]; a config runs in the most recently
    registered mode whose ``applies`` accepts it.

    Attributes:
        name: the mode's name (in messages and ``taskrl info``).
        summary: one line on what the mode is.
        applies: ``config -> bool``: whether this mode runs the config.
        make_loop: ``(parts, bookkeeping) -> loop``, a loop with ``run(env_seed) -> LoopState``.
        loops: the algorithm kinds the mode runs (``off_policy``, ``on_policy``, ``offline``); another is a
            `ConfigError` on ``algo``.
        axis: what ``total_steps``, evaluation and checkpoint intervals count: ``env_steps`` or ``updates``.
        trainer_env: the env this process builds: ``copies`` (``num_envs`` copies it steps), ``one`` (one
            copy for spaces and rewards; others step elsewhere) or ``spaces`` (the family's spaces only, where
            it can give them without an env: nothing is stepped while training).
        own_steps: ``(config, env) -> transitions`` the mode collects into the replay itself (replay sizing).
        prepare: ``parts -> None`` once the parts are built, before anything is written (a cluster to reach,
            a dataset to read); it may add to ``parts.on_close``.
        evaluate_first: whether a new run evaluates before its first step (offline, the untrained policy
            says nothing the dataset does not, and a multi-task evaluation costs minutes).
        selected_by: the run-level setting that switches this mode on (``distributed``, ``offline``); empty for a
            mode chosen by the algorithm alone. Two switched modes that both apply are one error naming both.
        check: ``config -> None``: what the mode asks of the run's settings, a `ConfigError` naming the setting
            otherwise (data to learn from, settings that act in one process only); None: nothing to ask.
    """

    name: str
    summary: str
    applies: Callable[[TrainConfig], bool]
    make_loop: Callable[[RunParts, Bookkeeping], Any]
    loops: tuple[str, ...]
    axis: Literal["env_steps", "updates"] = "env_steps"
    trainer_env: Literal["copies", "one", "spaces"] = "copies"
    own_steps: Callable[[TrainConfig, BatchedEnv], int] = steps_and_last_of_each_copy
    prepare: Callable[[RunParts], None] | None = None
    evaluate_first: bool = True
    selected_by: str = ""
    check: Callable[[TrainConfig], None] | None = None
