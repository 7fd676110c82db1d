"""Data sharing between tasks: the grid and point tasks, online and offline."""

from __future__ import annotations

from taskrl.presets.fragments import GRID_SHARING, POINT_OFFLINE, POINT_SHARING
from taskrl.presets.spec import Preset

PRESETS: dict[str, Preset] = {
    "grid-sharing-dqn": Preset(
        "DQN on the grid tasks, top-left-avoid with 10x less data, every task's batch half from all tasks' data",
        GRID_SHARING,
    ),
    "point-sharing-sac": Preset(
        "SAC on the point tasks, right-edge with 10x less data, every task's batch half from all tasks' data",
        POINT_SHARING,
    ),
    "point-sharing-offline": Preset(
        "offline SAC + CQL on the point tasks from expert / medium / random datasets, conservative sharing (CDS)",
        POINT_OFFLINE,
    ),
}
