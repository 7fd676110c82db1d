"""Runs in one process that step their own envs: off-policy (a replay) and on-policy (rollouts)."""

from __future__ import annotations

from taskrl.agents.registry import algorithm
from taskrl.runmodes.spec import RunMode
from taskrl.training.bookkeeping import Bookkeeping
from taskrl.training.offpolicy import LoopSchedule, OffPolicyLoop
from taskrl.training.onpolicy import OnPolicyLoop
from taskrl.wiring.parts import RunParts

__all__ = ["OFF_POLICY", "ON_POLICY"]


def off_policy_loop(parts: RunParts, books: Bookkeeping) -> OffPolicyLoop:
    """Collect into the replay and update from it, in turn (``updates_per_step`` updates per env step)."""
    c = parts.config
    schedule = LoopSchedule(
        total_steps=c.total_steps,
        batch_size=c.batch_size,
        learning_starts=c.learning_starts,
        updates_per_step=c.updates_per_step,
        offline_updates=c.data.offline_updates,
        updates_per_call=c.updates_per_call,
        scripted_exploration=c.data.scripted_exploration,
        scripted_steps=c.data.scripted_steps,
    )
    return OffPolicyLoop(parts.env, parts.agent, parts.replay, parts.sampler, schedule, books, parts.generator)


def on_policy_loop(parts: RunParts, books: Bookkeeping) -> OnPolicyLoop:
    """Roll out, update on the rollout, drop it."""
    return OnPolicyLoop(parts.env, parts.agent, parts.config.total_steps, books, parts.generator)


OFF_POLICY = RunMode(
    name="off_policy",
    summary="one process: collect into the replay and update from it in turn",
    applies=lambda config: algorithm(config.algo).loop == "off_policy",
    make_loop=off_policy_loop,
    loops=("off_policy",),
)

ON_POLICY = RunMode(
    name="on_policy",
    summary="one process: roll out, then update on the rollout",
    applies=lambda config: algorithm(config.algo).loop == "on_policy",
    make_loop=on_policy_loop,
    loops=("on_policy",),
)
