"""Can the grasp critic's network see a grasp? A supervised probe, apart from reinforcement learning.

The question QT-Opt's critic must answer at a close is "would closing here hold an object?". This probe
teaches the critic's own network (``ImageStateInput``: the conv encoder, DrQ's head, then the preset's 256 x 256
layers) that answer directly, with the simulator's labels, on grasp-bin pictures whose gripper is placed near an
object (70%) or anywhere (30%), so about one in six closes would hold. If the network cannot learn it here,
no amount of Q-learning will; if it can, how fast it does bounds how fast the critic can.

Arms (``INIT:PAD[:ENCODER]``): the conv layers' initialisation (``orthogonal``: taskrl's, as DrQ's; ``torch``:
PyTorch's default), the random shift (pixels of pad) and the encoder (``conv``, the preset's, or ``resnet``). Reported: the held-out AUC every 1,000 updates (batch 64, Adam 3e-4, one torch
thread).

    .venv/bin/python benchmarks/grasp_probe.py --arms orthogonal:4 torch:4 orthogonal:4:resnet --updates 6000 --write
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402
from taskrl.encoders import ImageStateInput, random_shift_moves  # noqa: E402
from taskrl.envs.grasp import Grasp, GraspSettings  # noqa: E402
from taskrl.types import PictureState  # noqa: E402

STATE = 5  # the grasp env's state vector


def rows_of(x: PictureState, rows: torch.Tensor | slice) -> PictureState:
    """The states ``rows`` of a batch."""
    return PictureState(x.vector[rows], x.pictures[rows])


def shifted(x: PictureState, pad: int, generator: torch.Generator, moved: bool = False) -> PictureState:
    """The states with their pictures shifted (DrQ's augmentation); ``moved``: the gripper's x, y in the state
    vector moved with the picture (the grasp env's picture coordinates: 1/64 of the bin per pixel)."""
    pictures, moves = random_shift_moves(x.pictures[:, 0], pad, generator)
    vector = x.vector
    if moved:
        vector = vector.clone()
        vector[:, 0] += moves[:, 1] / pictures.shape[2]  # x follows the columns
        vector[:, 1] += moves[:, 0] / pictures.shape[1]  # y follows the rows
    return PictureState(vector, pictures[:, None])


def placed_bins(n: int, seed: int, spread: float) -> tuple[Grasp, PictureState, torch.Generator]:
    """``(env, flat inputs [n, 5 + 64*64*3], generator)``: ``n`` bins with the gripper within ``spread`` of an object
    (70%) or anywhere, at a random yaw."""
    env = Grasp(GraspSettings(), num_envs=n, seed=seed)
    env.reset()
    g = torch.Generator().manual_seed(seed)
    pick = torch.randint(env.settings.num_objects, (n,), generator=g)
    near = env.centre[torch.arange(n), pick] + (torch.rand(n, 2, generator=g) - 0.5) * spread
    anywhere = torch.rand(n, 2, generator=g)
    env.gripper = torch.where((torch.rand(n, generator=g) < 0.7)[:, None], near, anywhere).clamp(0, 1)
    env.yaw = math.pi * torch.rand(n, generator=g)
    obs = env._obs()
    return env, PictureState(obs["observation"], obs["image"][:, None]), g


def labelled_states(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(states (the gripper's 5 numbers and the 64x64 picture), holds [n])``: would closing where the gripper is hold
    an object?"""
    env, x, _ = placed_bins(n, seed, 0.1)
    return x, env.holdable().any(1).float()


def auc(score: torch.Tensor, label: torch.Tensor) -> float:
    """Area under the ROC curve: the chance a holding state scores above a missing one."""
    ranks = torch.empty_like(score)
    ranks[score.argsort()] = torch.arange(len(score), dtype=score.dtype)
    positives = int(label.sum())
    return float((ranks[label > 0].sum() - positives * (positives - 1) / 2) / (positives * (len(score) - positives)))


def probe(init: str, pad: int, kind: str, updates: int, train: tuple, test: tuple, seed: int) -> list[dict]:
    torch.manual_seed(seed)
    encoder = ImageStateInput(STATE, (64, 64, 3), kind, 50)
    if init == "torch":
        for layer in encoder.trunk:
            if isinstance(layer, nn.Conv2d):
                layer.reset_parameters()
    net = nn.Sequential(encoder, nn.Linear(encoder.out_dim, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 1))
    optimiser = torch.optim.Adam(net.parameters(), 3e-4)
    (x, y), (x_test, y_test) = train, test
    g = torch.Generator().manual_seed(seed)
    curve, start = [], time.perf_counter()
    for step in range(updates + 1):
        if step % 1000 == 0:
            with torch.no_grad():
                score = net(x_test).squeeze(1)
            curve.append({"updates": step, "auc": auc(score, y_test), "seconds": time.perf_counter() - start})
            print(init, pad, kind, curve[-1], flush=True)
        rows = torch.randint(x.rows, (64,), generator=g)
        loss = nn.functional.binary_cross_entropy_with_logits(net(shifted(rows_of(x, rows), pad, g)).squeeze(1), y[rows])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return curve


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--arms", nargs="+", default=["orthogonal:4", "torch:4"], help="INIT:PAD[:ENCODER]")
    parser.add_argument("--updates", type=int, default=6000)
    parser.add_argument("--train-states", type=int, default=40_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write", action="store_true", help="replace the RESULTS section")
    args = parser.parse_args()
    torch.set_num_threads(1)
    train, test = labelled_states(args.train_states, 1), labelled_states(4_000, 2)
    results = []
    for arm in args.arms:
        init, pad, kind = (arm.split(":") + ["conv"])[:3]
        curve = probe(init, int(pad), kind, args.updates, train, test, args.seed)
        results.append({"init": init, "pad": int(pad), "encoder": kind, "curve": curve})
    raw = Path(__file__).parent / "results" / "grasp_probe.json"
    raw.write_text(json.dumps({"holding_share": float(test[1].mean()), "arms": results}, indent=2) + "\n")
    if args.write:
        report(results, args, float(test[1].mean()))


def report(results: list[dict], args, share: float) -> None:
    steps = [row["updates"] for row in results[0]["curve"]]
    lines = [
        f"`{' '.join(['.venv/bin/python benchmarks/grasp_probe.py', '--arms', *args.arms, '--updates', str(args.updates)])}`: "
        f"the grasp critic's network (the encoder, 50 features, 256 x 256) taught by the simulator whether closing "
        f"where the gripper is would hold an object; {args.train_states:,} training bins, 4,000 held-out ones "
        f"({share:.0%} of them would hold); batch 64, Adam 3e-4, one torch thread, seed {args.seed}. "
        "Held-out AUC (0.5: no better than chance):",
        "",
        "| conv init | shift pad | encoder | " + " | ".join(f"{s:,}" for s in steps) + " |",
        "|---|---|---|" + "---|" * len(steps),
    ]
    for r in results:
        aucs = " | ".join(f"{row['auc']:.2f}" for row in r["curve"])
        lines.append(f"| {r['init']} | {r['pad']} | {r['encoder']} | {aucs} |")
    append_results("Grasp critic probe: can the critic's network see a grasp (supervised, apart from RL)", "\n".join(lines))


if __name__ == "__main__":
    main()
