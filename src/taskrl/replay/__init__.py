"""Replay: episode storage counted in transitions, sampling and relabelling."""

from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeRecorder, Episodes, EpisodeStaging
from taskrl.replay.hindsight import STRATEGIES, HindsightRelabeler
from taskrl.replay.sampling import RecentMixSampler, TaskBalancedSampler
from taskrl.replay.storage import EpisodeReplay

__all__ = [
    "Batch",
    "EpisodeRecorder",
    "EpisodeReplay",
    "EpisodeStaging",
    "Episodes",
    "HindsightRelabeler",
    "RecentMixSampler",
    "STRATEGIES",
    "TaskBalancedSampler",
]
