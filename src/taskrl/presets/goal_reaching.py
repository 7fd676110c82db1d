"""Goal-conditioned presets: bit flipping (DQN + HER), PointReach, PixelReach and PixelPush, Fetch."""

from __future__ import annotations

from taskrl.presets.fragments import FETCH, FETCHPUSH, PIXELPUSH, POINTREACH, QTOPT, SAC
from taskrl.presets.spec import Preset

PRESETS: dict[str, Preset] = {
    "bitflip-her": Preset(
        "DQN + hindsight relabelling (future, k=4) on 15-bit flipping with random start and target",
        {"n_bits": 15, "her": "future", "her_k": 4, "total_steps": 60_000},
    ),
    "bitflip50-her": Preset(
        "DQN + hindsight relabelling on 50-bit flipping, the paper's hardest case: 64 envs and the "
        "paper's 0.05 updates per env step (more fresh data per update)",
        {
            "n_bits": 50,
            "her": "future",
            "her_k": 4,
            "num_envs": 64,
            "updates_per_step": 0.05,
            "total_steps": 2_000_000,
            "eval_interval": 20_000,
        },
    ),
    "bitflip-dqn": Preset(
        "plain DQN, no relabelling, on 15-bit flipping: the contrast case that fails beyond ~13 bits",
        {"n_bits": 15, "her": "none", "total_steps": 60_000},
    ),
    "pointreach-sac-her": Preset(
        "SAC + hindsight relabelling on PointReach, a 2-D point moving to a random goal (sparse reward)",
        {**POINTREACH, **SAC},
    ),
    "pixelreach-sac-her": Preset(
        "SAC + hindsight relabelling on PixelReach: PointReach seen as a 32x32 picture, the goal given as a picture; "
        "random shifts of up to 2 pixels",
        {**POINTREACH, **SAC, "env": "pixelreach", "shift": 2, "total_steps": 100_000},
    ),
    "pixelpush-sac-her": Preset(
        "SAC + hindsight relabelling on PixelPush: push a block to a goal shown as a picture (32x32 scene and goal "
        "pictures, the pusher's position), random shifts of up to 2 pixels",
        {**PIXELPUSH, "shift": 2},
    ),
    "pixelpush-state-sac-her": Preset(
        "SAC + hindsight relabelling on PixelPush from positions (pusher, block, goal): the control without pictures",
        {**PIXELPUSH, "observation": "state"},
    ),
    "pixelpush-state-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on PixelPush from positions (pusher, block, goal): the five-minute check that "
        "QT-Opt learns to push (64x64 Q-network, 0.25 updates per env step, 150k env steps)",
        {**PIXELPUSH, **QTOPT, "observation": "state", "hidden_sizes": (64, 64), "total_steps": 150_000},
    ),
    "pointreach-qtopt-her": Preset(
        "QT-Opt (Q-learning, CEM argmax) + hindsight relabelling on PointReach (sparse reward)",
        {**POINTREACH, **QTOPT},
    ),
    "fetchreach-sac-her": Preset(
        "SAC + hindsight relabelling on FetchReach-v4 (gymnasium-robotics, MuJoCo)",
        {**FETCH, **SAC, "env": "fetchreach", "total_steps": 20_000},
    ),
    "fetchreach-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchReach-v4; a 128x128 Q-network keeps CEM targets affordable",
        {**FETCH, **QTOPT, "env": "fetchreach", "total_steps": 20_000, "hidden_sizes": (128, 128)},
    ),
    "fetchpush-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPush-v4 (the paper's scale: 8 copies, up to 2M env steps; hours on CPU)",
        {**FETCH, **SAC, **FETCHPUSH, "hidden_sizes": (256, 256, 256), "updates_per_step": 0.25},
    ),
    "fetchpush-qtopt-her": Preset(
        "QT-Opt + hindsight relabelling on FetchPush-v4 (8 copies, up to 2M env steps; hours on CPU); a 128x128 "
        "Q-network and 0.1 updates per env step keep its CEM targets within SAC's time per env step",
        {**FETCH, **QTOPT, **FETCHPUSH, "hidden_sizes": (128, 128), "updates_per_step": 0.1},
    ),
    "fetchpickandplace-sac-her": Preset(
        "SAC + hindsight relabelling on FetchPickAndPlace-v4 (~4M env steps in the paper; hours on CPU)",
        {
            **FETCH,
            **SAC,
            "env": "fetchpickandplace",
            "num_envs": 8,
            "total_steps": 4_000_000,
            "eval_interval": 50_000,
            "hidden_sizes": (256, 256, 256),
        },
    ),
}
