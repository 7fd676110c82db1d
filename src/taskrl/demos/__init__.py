"""Demonstrations: scripted experts, collection into Minari datasets, and the tensors imitation trains on."""

from taskrl.demos.dataset import Demonstrations, Episode, dataset_card, read_demonstrations, write_dataset

__all__ = ["Demonstrations", "Episode", "dataset_card", "read_demonstrations", "write_dataset"]
