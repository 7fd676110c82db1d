"""Peak memory a checkpoint write adds on top of the replay it saves.

A replay of 2M transitions of 40-bit flipping (64 copies), every page touched, is saved with
``save_checkpoint``; the process's peak RSS before and after the save is compared.

    .venv/bin/python benchmarks/checkpoint_memory.py [--write]
"""

from __future__ import annotations

import argparse
import resource
import tempfile

from common import append_results
from taskrl.checkpoint import save_checkpoint
from taskrl.envs import BitFlip
from taskrl.replay import EpisodeReplay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--capacity", type=int, default=2_000_000)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    env = BitFlip(40, num_envs=64)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space, args.capacity, num_envs=64, horizon=env.horizon)
    tables = [*replay.obs.values(), *replay.steps.values(), replay.step_episode]
    for table in tables:
        table.fill_(1)
    size = sum(t.nbytes for t in tables) / 2**20
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with tempfile.TemporaryDirectory() as folder:
        save_checkpoint(folder, {"replay": replay.state_dict()}, 0)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    line = (
        f"| {args.capacity:,} | {size:.0f} MiB | {before:.0f} MiB | {after:.0f} MiB | +{after - before:.0f} MiB "
        f"({(after - before) / size:.2f}x the replay) |"
    )
    print(line)
    if args.write:
        append_results(
            "Checkpoint memory: what a save adds on top of the replay",
            "| replay capacity (transitions) | replay size | peak RSS before the save | after | added |\n"
            "|---|---|---|---|---|\n" + line,
        )


if __name__ == "__main__":
    main()
