"""Named, documented starting points for ``taskrl train PRESET``, one file per kind of task beside the families they
use (goal reaching, grasping, multi-task, imitation, data sharing); `PRESETS` holds them all, in that order."""

from __future__ import annotations

from taskrl.config import TrainConfig
from taskrl.errors import ConfigError
from taskrl.overrides import with_overrides
from taskrl.presets import goal_reaching, grasping, imitation, multitask, sharing
from taskrl.presets.spec import Preset

__all__ = ["PRESETS", "Preset", "preset_config"]

#: name -> preset, every file's in turn
PRESETS: dict[str, Preset] = {
    **goal_reaching.PRESETS,
    **grasping.PRESETS,
    **multitask.PRESETS,
    **imitation.PRESETS,
    **sharing.PRESETS,
}


def preset_config(name: str) -> TrainConfig:
    """The configuration of a named preset; unknown names raise `ConfigError`."""
    if name not in PRESETS:
        raise ConfigError("preset", f"unknown preset {name!r}; allowed: {', '.join(PRESETS)}")
    return with_overrides(TrainConfig(), PRESETS[name].overrides)
