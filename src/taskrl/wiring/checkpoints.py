"""Writing a run's checkpoints and restoring a run from its last one."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from taskrl import config as config_io
from taskrl.checkpoint import checkpoint_at, load_checkpoint, read_checkpoint, save_checkpoint
from taskrl.config import TrainConfig
from taskrl.errors import ConfigError, reason
from taskrl.training.bookkeeping import LoopState
from taskrl.wiring.parts import RunParts

__all__ = ["checkpointer", "load_agent_state", "restore", "restore_checked", "start_from_run"]


def load_agent_state(agent: Any, state: dict[str, Any], where: Path) -> None:
    """``agent.load_state_dict(state)``; a checkpoint whose parts do not fit the run's ``config.json`` (another
    preset's settings over it, extra or missing keys, other shapes) is one `ConfigError` naming it."""
    try:
        agent.load_state_dict(state)
    except (KeyError, RuntimeError, ValueError) as error:
        raise ConfigError(
            "checkpoint", f"{where} does not fit the run's config.json (another run's settings?): {reason(error, 160)}"
        ) from None


def start_from_run(parts: RunParts, run_dir: str | Path) -> str:
    """Load the agent of another run's last checkpoint into a new run's agent (``--init-from``); a note saying
    which. Anything that keeps it from fitting (no run there, another algorithm or env, other network sizes) is one
    `ConfigError` for ``init_from``."""
    run_dir, config = Path(run_dir), parts.config
    try:
        other = config_io.load(run_dir / "config.json")
        folder = checkpoint_at(run_dir / "checkpoints")
        saved = read_checkpoint(folder, ("agent", "loop"), parts.device)
        state, loop = saved["agent"], saved.get("loop", {})
    except (OSError, KeyError, ValueError) as error:
        raise ConfigError("init_from", f"{run_dir} holds no run to start from ({reason(error, 160)})") from None
    if (other.algo, other.env) != (config.algo, config.env):
        raise ConfigError(
            "init_from",
            f"{run_dir} trained {other.algo} on {other.env}, this run is {config.algo} on {config.env}; "
            "start from a run of the same algorithm and env",
        )
    try:
        parts.agent.load_state_dict(state)
    except (KeyError, RuntimeError, ValueError) as error:
        raise ConfigError(
            "init_from", f"the agent of {run_dir} does not fit this run's networks (other sizes?): {_first_cause(error)}"
        ) from None
    trained = f"{loop.get('env_steps', 0):,} env steps, {loop.get('updates', 0):,} updates"
    return f"the agent starts from {run_dir}'s last checkpoint ({trained}); this run counts from 0"


def _first_cause(error: BaseException) -> str:
    """The first line of ``error`` that says something (torch's ``load_state_dict`` opens with a heading line)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip() and not line.strip().endswith(":")]
    return lines[0][:200] if lines else reason(error)


def restore(parts: RunParts, run_dir: Path) -> LoopState:
    """Load the last checkpoint of ``run_dir`` into the parts; the loop state to continue from."""
    saved = load_checkpoint(run_dir / "checkpoints", ("agent", "replay", "loop"), parts.device)
    parts.agent.load_state_dict(saved["agent"])  # a part that does not fit: _restore_checked says which settings changed
    if "replay" in saved and parts.replay is not None:
        parts.replay.load_state_dict(saved["replay"])
    loop_saved = dict(saved["loop"])
    parts.generator.set_state(loop_saved.pop("generator").cpu())
    return LoopState(**loop_saved)


def restore_checked(parts: RunParts, run_dir: Path, saved: TrainConfig, config: TrainConfig) -> LoopState:
    """`restore`, with a checkpoint that does not fit the settings given refused in one line
    (before the run's config.json is rewritten, so the run stays resumable as it was)."""
    try:
        return restore(parts, run_dir)
    except (RuntimeError, KeyError, ValueError, TypeError) as error:
        if isinstance(error, ConfigError):
            raise
        before, after = config_io.to_dict(saved), config_io.to_dict(config)
        changed = sorted(_changed_paths(before, after))
        what = f"the settings changed ({', '.join(changed)})" if changed else "its settings"
        raise ConfigError(
            "resume",
            f"the checkpoint in {run_dir} does not fit {what}: {reason(error)}; resume without changing them (the run is unchanged)",
        ) from None


def _changed_paths(before: Any, after: Any, prefix: str = "") -> list[str]:
    if isinstance(before, dict) and isinstance(after, dict):
        keys = sorted(set(before) | set(after))
        return [p for k in keys for p in _changed_paths(before.get(k), after.get(k), f"{prefix}{k}.")]
    return [] if before == after else [prefix.rstrip(".").rsplit(".", 1)[-1]]


def checkpointer(parts: RunParts, run_dir: Path, axis: str) -> Callable[[LoopState], None]:
    """``(loop state) -> None`` writing agent, loop and (``save_replay``) replay parts, named by the
    run's progress on ``axis`` (``env_steps``; ``updates`` for runs that step no env)."""

    def checkpoint(state: LoopState) -> None:
        saved: dict[str, Any] = {
            "agent": parts.agent.state_dict(),
            "loop": {**dataclasses.asdict(state), "generator": parts.generator.get_state()},
        }
        # an --offline run's replay is its stored data, unchanged: read again from there on resume, not copied here
        if parts.config.checkpoints.save_replay and parts.replay is not None and not parts.config.data.offline:
            saved["replay"] = parts.replay.state_dict()
        save_checkpoint(run_dir / "checkpoints", saved, state.progress(axis))

    return checkpoint
