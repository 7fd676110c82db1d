"""The CPU micro-benchmarks behind ``nets.Linear``: its product layouts, and what they buy in an update.

- ``products``: microseconds of each matrix product of a layer, plain (what ``nn.Linear`` and its
  autograd run) against the layout ``nets.Linear`` takes, and whether the bits are the same;
- an A/B of the compiled DQN (256, 256) / 256 agent update with ``nets.Linear`` and ``nn.Linear``;

    cd benchmarks && ../.venv/bin/python cpu_layouts.py [--write]
"""

from __future__ import annotations

import time

import torch
import torch.nn.functional as F

from common import alternating_blocks, append_results, micro_benchmark_args

#: (rows, in_features, out_features): the DQN bit-flipping n = 15 layers at batch 256, FetchReach's SAC
#: first layers, an MT10 first layer, and heads of other widths
LAYERS = [
    (256, 30, 256),
    (256, 256, 256),
    (256, 256, 15),
    (256, 13, 256),
    (256, 17, 256),
    (256, 256, 8),
    (256, 256, 30),
    (256, 256, 20),
    (1280, 49, 400),
    (1280, 400, 13),
]


def _us(fn, seconds: float = 0.3) -> float:
    for _ in range(20):
        fn()
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        fn()
        n += 1
    return (time.perf_counter() - start) / n * 1e6


def _layer_row(m: int, k: int, n: int) -> str:
    x, w, b, g = torch.randn(m, k), torch.randn(n, k), torch.randn(n), torch.randn(m, n)
    pad = -n % 16
    padded_w, padded_b = F.pad(w, (0, 0, 0, pad)), F.pad(b, (0, pad))
    plain = _us(lambda: F.linear(x, w, b))
    padded = _us(lambda: F.linear(x, F.pad(w, (0, 0, 0, pad)), F.pad(b, (0, pad)))[:, :n]) if pad else plain
    same_fwd = torch.equal(F.linear(x, w, b), F.linear(x, padded_w, padded_b)[:, :n])
    grad_plain, grad_wide = _us(lambda: g.t().mm(x)), _us(lambda: x.t().mm(g).t())
    same_grad = torch.equal(g.t().mm(x), x.t().mm(g).t())
    return (
        f"| {m}, {k} -> {n} | {plain:.0f} / {padded:.0f} | {'yes' if same_fwd else 'no'} | "
        f"{grad_plain:.0f} / {grad_wide:.0f} | {'yes' if same_grad else 'no'} |"
    )


def products() -> str:
    rows = [
        "| rows, in -> out | forward: plain / padded to 16 | same bits | weight gradient: g^T x / (x^T g)^T | same bits |",
        "|---|---|---|---|---|",
    ]
    return "\n".join(rows + [_layer_row(*shape) for shape in LAYERS])


def agents_side_by_side(rounds: int = 10, block: int = 150) -> str:
    """The compiled DQN (256, 256) / 256 update of bit flipping n = 15 with ``nets.Linear`` and with
    ``nn.Linear``, timed in alternating blocks in one process (the machine's drift hits both alike)."""
    from learner_speed import bitflip_agent_and_batch, with_plain_layers

    laid_out, batch, _ = bitflip_agent_and_batch(256, (256, 256), False)
    plain = with_plain_layers(bitflip_agent_and_batch(256, (256, 256), False)[0])
    agents = {"nets.Linear": laid_out, "nn.Linear": plain}
    for agent in agents.values():
        agent.compile("default", say=lambda line: None)
        for _ in range(120):
            agent.update(batch)

    def run(agent):
        for _ in range(block):
            agent.update(batch)
        return block

    times = alternating_blocks({name: lambda agent=agent: run(agent) for name, agent in agents.items()}, rounds)
    median = {name: sorted(t)[len(t) // 2] for name, t in times.items()}
    return "\n".join(
        [
            f"| compiled DQN (256, 256) / 256 update, {rounds} alternating blocks of {block} | median ms | blocks (ms) |",
            "|---|---|---|",
            *(f"| {name} | {median[name]:.3f} | {', '.join(f'{t:.2f}' for t in times[name])} |" for name in agents),
            "",
            f"nn.Linear / nets.Linear: {median['nn.Linear'] / median['nets.Linear']:.3f}x.",
        ]
    )


def main() -> None:
    args = micro_benchmark_args(__doc__)
    table = (
        "One torch thread; microseconds per product (best layout of each row in the second and fourth "
        "columns where they differ).\n\n" + products() + "\n\n" + agents_side_by_side()
    )
    print(table)
    if args.write:
        append_results("CPU product layouts and the compiled Adam step", table)


if __name__ == "__main__":
    main()
