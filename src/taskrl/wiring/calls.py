"""One call of ``train``: its settings (preset, resumed run or file, with overrides), the env object it
names, the module that registers a user's gymnasium ids, its run directory's name, and what it warns of."""

from __future__ import annotations

import dataclasses
import datetime
import importlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console

from taskrl import config as config_io
from taskrl.agents.compile_rule import cached_calls, choose_compile, machine_compiled_before, remember_compiled
from taskrl.agents.registry import algorithm
from taskrl.config import TrainConfig
from taskrl.envs.registry import ENV_FAMILIES, family_for_source
from taskrl.errors import ConfigError
from taskrl.overrides import with_overrides
from taskrl.presets import preset_config
from taskrl.rundir import atomic_write_text

if TYPE_CHECKING:
    from taskrl.agents.spec import AlgorithmSpec
    from taskrl.envs.spec import EnvFamily

__all__ = [
    "budget_warnings",
    "default_run_dir",
    "env_source",
    "import_env_module",
    "print_notes",
    "resolve_config",
    "run_title",
    "settle_compile",
]

RUN_INFO = "run.json"


def run_title(run_dir: Path, preset: str | None, config: TrainConfig) -> str:
    """The run's name: its preset, recorded in ``run.json`` when it starts, so a resumed run keeps it."""
    info = run_dir / RUN_INFO
    if preset is not None:
        atomic_write_text(info, json.dumps({"preset": preset}) + "\n")
        return preset
    try:
        recorded = json.loads(info.read_text()).get("preset")
    except (OSError, ValueError, AttributeError):
        recorded = None
    return recorded if isinstance(recorded, str) and recorded else f"{config.env}-{config.algo}"


def default_run_dir(name: str) -> Path:
    return Path("runs") / f"{name}-{datetime.datetime.now():%Y%m%d-%H%M%S}"


def env_source(overrides: dict[str, Any]) -> Any:
    """Read ``env=`` of `train`: a family name stays a setting, a gymnasium id becomes
    ``env_id`` of the ``gym`` family, and a Python object (a factory, a TaskSet) is returned as
    the source its family builds envs from."""
    value = overrides.get("env")
    if value is None:  # env=None: not given
        overrides.pop("env", None)
        return None
    if isinstance(value, str) and value in ENV_FAMILIES:
        return None
    if isinstance(value, str):
        overrides.update(env="gym", env_id=value)
        return None
    overrides["env"] = family_for_source(value).name
    return value


def import_env_module(name: str) -> None:
    """Import the module that registers a user's gymnasium ids (``--env-module``)."""
    if not name:
        return
    try:
        importlib.import_module(name)
    except ImportError as error:
        raise ConfigError("env_module", f"cannot import {name!r}: {error}") from None


def print_notes(console: Console | None, notes: list[str]) -> None:
    out = console or Console(stderr=True)
    for line in notes:
        out.print(line if line.startswith("warning: ") else f"note: {line}", soft_wrap=True, markup=False)


def resolve_config(
    preset: str | None,
    resume: str | Path | None,
    overrides: dict[str, Any],
    notes: list[str] | None = None,
    base: TrainConfig | None = None,
) -> TrainConfig:
    """The settings a call would train with: the resumed run's, a given base config, or the preset's,
    with ``overrides`` applied (what changing env or algo kept or dropped goes to ``notes``)."""
    notes = [] if notes is None else notes
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / "config.json").exists():
            raise ConfigError("resume", f"{run_dir} is not a run directory (no config.json)")
        start = config_io.load(run_dir / "config.json")
    else:
        start = base if base is not None else preset_config(preset)
    config = with_overrides(start, overrides, notes)
    notes += [f"warning: {w}" for w in budget_warnings(config)]
    return config


def settle_compile(config: TrainConfig, spec: AlgorithmSpec, family: EnvFamily, notes: list[str]) -> TrainConfig:
    """``config`` with ``compile`` and ``updates_per_call`` settled where they are ``auto``, for its resolved algorithm
    and env family (a `RunPlan`'s); why goes first in ``notes``."""
    many = spec.loop == "off_policy" and not config.cluster.distributed and not config.data.offline
    pictures = family.images
    cached = cached_calls(config) if spec.compiles else set()
    choice = choose_compile(config, spec.compiles, many, pictures, cached, machine_compiled_before() if spec.compiles else True)
    if choice.reason:  # the run's first line
        notes.insert(0, choice.reason)
    return dataclasses.replace(config, compile=choice.mode, updates_per_call=choice.updates_per_call)


def remember_compiled_graphs(config: TrainConfig, agent: Any) -> None:
    """After a run: mark the shapes whose update graphs compiled (and did not fall back), for later runs' estimate."""
    for name, per_call in (("step", 1), ("step_many", config.updates_per_call)):
        step = getattr(agent, name, None)
        if step is not None and getattr(step, "active", False) and getattr(step, "compile_seconds", 0.0) > 0:
            remember_compiled(config, per_call)


def budget_warnings(config: TrainConfig) -> list[str]:
    """Budgets that make a run do less than its settings suggest (said before training, not refused)."""
    c, out = config, []
    if algorithm(c.algo).loop == "off_policy" and not c.data.offline:  # an offline run's total_steps are updates
        if c.learning_starts >= c.total_steps:
            out.append(
                f"learning_starts={c.learning_starts:,} >= total_steps={c.total_steps:,}: the run collects "
                f"data and makes no gradient update"
            )
        elif c.updates_per_step * (c.total_steps - c.learning_starts) < 1:
            out.append(
                f"updates_per_step={c.updates_per_step} over {c.total_steps - c.learning_starts:,} env steps "
                f"after learning_starts is less than one gradient update"
            )
    elif algorithm(c.algo).loop == "on_policy":
        rollout = getattr(c.algo_settings, "rollout_steps", 1) * c.num_envs
        if c.total_steps < rollout:
            out.append(f"total_steps={c.total_steps:,} is less than one rollout ({rollout:,} env steps): one rollout runs")
    return out
