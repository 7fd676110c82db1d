"""Named, documented starting points for ``taskrl train PRESET``."""

from __future__ import annotations

import dataclasses

from taskrl.config import ConfigError, TrainConfig, with_overrides


@dataclasses.dataclass(frozen=True)
class Preset:
    description: str
    overrides: dict


PRESETS: dict[str, Preset] = {
    "bitflip-her": Preset(
        "DQN + hindsight relabelling (future, k=4) on 15-bit flipping with random start and target",
        {"n_bits": 15, "her": "future", "her_k": 4, "total_steps": 60_000},
    ),
    "bitflip50-her": Preset(
        "DQN + hindsight relabelling on 50-bit flipping, the paper's hardest case: 64 envs and the "
        "paper's 0.05 updates per env step (more fresh data per update)",
        {"n_bits": 50, "her": "future", "her_k": 4, "num_envs": 64, "updates_per_step": 0.05,
         "total_steps": 2_000_000, "eval_interval": 20_000},
    ),
    "bitflip-dqn": Preset(
        "plain DQN, no relabelling, on 15-bit flipping: the contrast case that fails beyond ~13 bits",
        {"n_bits": 15, "her": "none", "total_steps": 60_000},
    ),
}


def preset_config(name: str) -> TrainConfig:
    """The configuration of a named preset; unknown names raise :class:`ConfigError`."""
    if name not in PRESETS:
        raise ConfigError("preset", f"unknown preset {name!r}; allowed: {', '.join(PRESETS)}")
    return with_overrides(TrainConfig(), PRESETS[name].overrides)
