"""Named, documented starting points for ``taskrl train PRESET``."""

from __future__ import annotations

import dataclasses

from taskrl.config import ConfigError, TrainConfig, with_overrides

# Goal reaching with continuous actions: the hindsight paper's Fetch settings where they apply
# (gamma 0.98, lr 1e-3, batch 256, relabelling future with k = 4; episodes never end on success).
_CONTINUOUS_HER = {"her": "future", "her_k": 4, "terminate_on_success": False, "batch_size": 256}
_SAC = {"algo": "sac", "epsilon_start": 1.0, "epsilon_end": 1.0}  # > 0: sample the policy while collecting
_QTOPT = {"algo": "qtopt", "epsilon_start": 0.3, "epsilon_end": 0.1, "epsilon_decay_steps": 20_000}
_POINTREACH = {**_CONTINUOUS_HER, "env": "pointreach", "num_envs": 16, "updates_per_step": 0.25,
               "learning_starts": 1_000, "eval_interval": 3_000, "total_steps": 40_000,
               "hidden_sizes": (64, 64), "lr": 1e-3, "gamma": 0.95}
_FETCH = {**_CONTINUOUS_HER, "num_envs": 2, "updates_per_step": 0.5, "learning_starts": 1_000,
          "eval_interval": 2_000, "eval_episodes": 100, "lr": 1e-3, "gamma": 0.98}


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
    "pointreach-sac-her": Preset(
        "SAC + hindsight relabelling on PointReach, a 2-D point moving to a random goal (sparse reward)",
        {**_POINTREACH, **_SAC},
    ),
    "pointreach-qtopt-her": Preset(
        "QT-Opt (Q-learning, CEM argmax) + hindsight relabelling on PointReach (sparse reward)",
        {**_POINTREACH, **_QTOPT},
    ),
    "fetchreach-sac-her": Preset(
        "SAC + hindsight relabelling on FetchReach-v4 (gymnasium-robotics, MuJoCo)",
        {**_FETCH, **_SAC, "env": "fetchreach", "total_steps": 20_000},
    ),
    "fetchreach-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchReach-v4; a 128x128 Q-network keeps CEM targets affordable",
        {**_FETCH, **_QTOPT, "env": "fetchreach", "total_steps": 20_000, "hidden_sizes": (128, 128)},
    ),
    "fetchpush-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPush-v4 (the paper's scale: ~2M env steps; hours on CPU)",
        {**_FETCH, **_SAC, "env": "fetchpush", "num_envs": 8, "total_steps": 2_000_000, "eval_interval": 50_000,
         "hidden_sizes": (256, 256, 256)},
    ),
    "fetchpush-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchPush-v4 (~2M env steps; hours on CPU)",
        {**_FETCH, **_QTOPT, "env": "fetchpush", "num_envs": 8, "total_steps": 2_000_000, "eval_interval": 50_000,
         "hidden_sizes": (256, 256)},
    ),
    "fetchpickandplace-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPickAndPlace-v4 (~4M env steps in the paper; hours on CPU)",
        {**_FETCH, **_SAC, "env": "fetchpickandplace", "num_envs": 8, "total_steps": 4_000_000,
         "eval_interval": 50_000, "hidden_sizes": (256, 256, 256)},
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
