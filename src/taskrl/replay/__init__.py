"""Replay: episode storage, sampling and relabelling."""

from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeRecorder, EpisodeReplay
from taskrl.replay.hindsight import STRATEGIES, HindsightRelabeler
from taskrl.replay.sampling import RecentMixSampler, TaskBalancedSampler

__all__ = [
    "Batch",
    "EpisodeRecorder",
    "EpisodeReplay",
    "HindsightRelabeler",
    "RecentMixSampler",
    "STRATEGIES",
    "TaskBalancedSampler",
]
