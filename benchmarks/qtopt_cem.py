"""The cost centre of QT-Opt: the Bellman target's cross-entropy-method argmax.

Times ``QTOptAgent.bellman_target`` for a batch of 256 states (20-d state input, 4-d actions,
FetchPush-sized) against the FLOP bound of the same work, for the paper's CEM (64 samples x
2 rounds, 6 elites), a cheaper first round, a warm start from the previous argmax, and smaller
Q-networks. The FLOP bound divides the multiply-adds of every network row by the machine's
measured matrix-multiply rate.

    .venv/bin/python benchmarks/qtopt_cem.py --write
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import torch

from common import append_results
from taskrl.agents.cem import CEMConfig
from taskrl.agents.qtopt import QTOptAgent, QTOptConfig
from taskrl.replay.batch import Batch

STATE_DIM, ACTION_DIM, BATCH = 20, 4, 256


def matmul_gflops() -> float:
    a, b = torch.randn(2048, 256), torch.randn(256, 256)
    for _ in range(5):
        a @ b
    t = time.perf_counter()
    for _ in range(50):
        a @ b
    return 50 * 2 * 2048 * 256 * 256 / (time.perf_counter() - t) / 1e9


def network_flops(rows: int, hidden: tuple[int, ...]) -> float:
    dims = [STATE_DIM + ACTION_DIM, *hidden, 1]
    return 2 * rows * sum(a * b for a, b in zip(dims[:-1], dims[1:]))


def timed(fn, repeats: int = 8) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return sorted(times)[len(times) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    gflops = matmul_gflops()

    obs = {"observation": torch.randn(BATCH, STATE_DIM // 2), "desired_goal": torch.randn(BATCH, STATE_DIM // 2)}
    batch = Batch(
        obs=obs,
        action=torch.zeros(BATCH, ACTION_DIM),
        reward=-torch.ones(BATCH),
        next_obs=obs,
        terminated=torch.zeros(BATCH, dtype=torch.bool),
        truncated=torch.zeros(BATCH, dtype=torch.bool),
        episode=torch.zeros(BATCH, dtype=torch.long),
        step=torch.zeros(BATCH, dtype=torch.long),
    )
    low_high = (-torch.ones(ACTION_DIM), torch.ones(ACTION_DIM))
    cases = [
        ("paper CEM: 64 + 64 samples, 6 elites", (256, 256), CEMConfig(), False, [64, 64]),
        ("first round 32 samples", (256, 256), CEMConfig(first_samples=32), False, [32, 64]),
        ("warm start from previous a*, 1 round", (256, 256), CEMConfig(), True, [64]),
        ("paper CEM, 128x128 Q-network", (128, 128), CEMConfig(), False, [64, 64]),
        ("paper CEM, 64x64 Q-network", (64, 64), CEMConfig(), False, [64, 64]),
    ]
    lines = [
        "| variant | Q-network | ms per target batch (256 states) | FLOP bound (ms) | ratio to bound | targets/s |",
        "|---|---|---|---|---|---|",
    ]
    for name, hidden, cem, warm, rounds in cases:
        agent = QTOptAgent(
            ("observation", "desired_goal"),
            STATE_DIM,
            low_high,
            dataclasses.replace(QTOptConfig(), hidden_sizes=hidden, cem=cem, normalize_inputs=False),
        )
        previous = agent.bellman_target(batch, return_action=True)[1] if warm else None
        seconds = timed(lambda agent=agent, previous=previous: agent.bellman_target(batch, warm_start=previous))
        rows = BATCH * sum(rounds) + BATCH  # CEM rows, plus the second target network at a*
        bound = network_flops(rows, hidden) / (gflops * 1e9)
        lines.append(
            f"| {name} | {hidden} | {seconds * 1e3:.1f} | {bound * 1e3:.1f} | {seconds / bound:.2f}x | {1 / seconds:.0f} |"
        )
        print(lines[-1], flush=True)
    table = "\n".join(lines)
    print(f"matmul rate: {gflops:.0f} GFLOP/s (2048x256 @ 256x256, {args.threads} thread(s))")
    if args.write:
        append_results(
            "QT-Opt: cost of the CEM Bellman target",
            f"torch threads {args.threads}; measured matrix-multiply rate {gflops:.0f} GFLOP/s. "
            "A QT-Opt update is this target plus one regression step.\n\n" + table,
        )


if __name__ == "__main__":
    main()
