"""Replay: episode storage, sampling and relabelling."""

from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeReplay
from taskrl.replay.hindsight import STRATEGIES, HindsightRelabeler
from taskrl.replay.sampling import TaskBalancedSampler

__all__ = ["Batch", "EpisodeReplay", "HindsightRelabeler", "STRATEGIES", "TaskBalancedSampler"]
