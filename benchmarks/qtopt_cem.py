"""The cost centre of QT-Opt: the Bellman target's cross-entropy-method argmax.

Times ``QTOptAgent.bellman_target`` for a batch of 256 states (20-d state input, 4-d actions,
FetchPush-sized) against the FLOP bound of the same work, for QT-Opt's default Bellman maximum (one round of 32
candidates, 4 elites), the paper's CEM (64 samples x 2 rounds, 6 elites), a warm start from the previous argmax,
and smaller Q-networks; then whole updates (target and regression) of the FetchPush preset's network with each
maximum, alternated A B A B in one process so both see the same machine. The FLOP bound divides the multiply-adds
of every network row by the machine's measured matrix-multiply rate.

    .venv/bin/python benchmarks/qtopt_cem.py --write
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import torch

from common import append_results
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


def update_rates(batch: Batch, low_high: tuple, default: dict, paper: dict, rounds: int) -> str:
    """Whole updates per second of the FetchPush preset's Q-network (128x128, batch 256) with each Bellman maximum,
    blocks of 20 updates alternated for ``rounds`` rounds; the median block of each."""
    agents = {
        name: QTOptAgent(
            ("observation", "desired_goal"),
            STATE_DIM,
            low_high,
            dataclasses.replace(QTOptConfig(), hidden_sizes=(128, 128), **search),
        )
        for name, search in (("default (1 x 32)", default), ("the paper's (2 x 64)", paper))
    }
    seconds: dict[str, list[float]] = {name: [] for name in agents}
    for _ in range(rounds):
        for name, agent in agents.items():
            start = time.perf_counter()
            for _ in range(20):
                agent.update(batch)
            seconds[name].append((time.perf_counter() - start) / 20)
    rates = {name: 1 / sorted(s)[len(s) // 2] for name, s in seconds.items()}
    first, second = rates.values()
    lines = [
        f"Whole updates (target and regression) of the FetchPush preset's network (128x128, batch 256), blocks of 20 "
        f"updates alternated for {rounds} rounds, median block:",
        "",
        "| Bellman maximum | updates/s |",
        "|---|---|",
        *(f"| {name} | {rate:.0f} |" for name, rate in rates.items()),
        "",
        f"The default makes {first / second:.2f}x the paper's updates per second.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=15, help="alternated rounds of the whole-update timing")
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
    default = {"target_samples": 32, "target_iterations": 1, "target_elites": 4}
    paper = {"target_samples": 64, "target_iterations": 2, "target_elites": 6}
    cases = [
        ("default: one round of 32, 4 elites", (256, 256), default, False, [32]),
        ("the paper's: 64 + 64 samples, 6 elites", (256, 256), paper, False, [64, 64]),
        ("warm start from previous a*, 1 round of 64", (256, 256), default, True, [64]),
        ("default, 128x128 Q-network", (128, 128), default, False, [32]),
        ("the paper's, 128x128 Q-network", (128, 128), paper, False, [64, 64]),
        ("default, 64x64 Q-network", (64, 64), default, False, [32]),
    ]
    lines = [
        "| variant | Q-network | ms per target batch (256 states) | FLOP bound (ms) | ratio to bound | targets/s |",
        "|---|---|---|---|---|---|",
    ]
    for name, hidden, search, warm, rounds in cases:
        agent = QTOptAgent(
            ("observation", "desired_goal"),
            STATE_DIM,
            low_high,
            dataclasses.replace(QTOptConfig(), hidden_sizes=hidden, normalize_inputs=False, **search),
        )
        previous = agent.bellman_target(batch, return_action=True)[1] if warm else None
        seconds = timed(lambda agent=agent, previous=previous: agent.bellman_target(batch, warm_start=previous))
        rows = BATCH * sum(rounds) + BATCH  # CEM rows, plus the second target network at a*
        bound = network_flops(rows, hidden) / (gflops * 1e9)
        lines.append(
            f"| {name} | {hidden} | {seconds * 1e3:.1f} | {bound * 1e3:.1f} | {seconds / bound:.2f}x | {1 / seconds:.0f} |"
        )
        print(lines[-1], flush=True)
    table = "\n".join(lines) + "\n\n" + update_rates(batch, low_high, default, paper, args.rounds)
    print(table)
    print(f"matmul rate: {gflops:.0f} GFLOP/s (2048x256 @ 256x256, {args.threads} thread(s))")
    if args.write:
        append_results(
            "QT-Opt: cost of the CEM Bellman target",
            f"torch threads {args.threads}; measured matrix-multiply rate {gflops:.0f} GFLOP/s. "
            "A QT-Opt update is this target plus one regression step.\n\n" + table,
        )


if __name__ == "__main__":
    main()
