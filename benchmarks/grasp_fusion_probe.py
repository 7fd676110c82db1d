"""Where should the action meet the picture? A supervised probe whose label depends on the action.

QT-Opt's critic must answer "would this action, closing, hold an object?". This probe teaches that answer with the
simulator's labels to two of QT-Opt's Q-networks on the fair grasp bin (64x64): ``flat`` (the conv encoder, 50
features, then the action joins an MLP: `StateActionQ` with `ImageStateInput`) and ``conv`` (QT-Opt's network: the
action and the gripper's state embedded and added to an intermediate conv feature map, then one more convolution:
`PictureActionQ`). Bins have the gripper near an object (70%) or anywhere; the action is uniform in the box with the
close on, and the label is whether that step's move and close holds. Arms are ``FUSION:PAD`` (pad: DrQ's random
shift in pixels, which moves the picture but not the gripper's position in the state vector) or ``FUSION:PAD:moved``
(the gripper's x, y moved with the picture, as ``--shift-coordinates`` does). Two more fusions ask whether the
critic can see the yaw: ``wide`` (the flat join from 256 picture features instead of 50), ``yaw`` (the flat join
given the gripper's yaw after the move, `PostMoveYaw`) and ``glimpse`` (the flat join from the whole picture's
features and those of the picture around the gripper turned into the jaws' frame, `taskrl.encoders.GlimpseInput`,
QT-Opt's ``fusion=glimpse``). Reported: held-out AUC every 1,000 updates (``--every``;
batch 64, Adam 3e-4, one torch thread), the same on the closes where only the yaw decides (over a square's, bar's or
ellipse's spine), and the time to score one candidate action (a batch of 64 states x 32 candidates, as the Bellman
maximum does).

    .venv/bin/python benchmarks/grasp_fusion_probe.py --arms flat:0 flat:1 flat:2 flat:4 conv:0 conv:2 --workers 2 --write
    .venv/bin/python benchmarks/grasp_fusion_probe.py --arms flat:4 wide:4 yaw:4 glimpse:4:moved --updates 12000 --every 2000 \
        --title 'Grasp critic probe: does the critic see the yaw' --raw grasp_probe_yaw.json --write
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).parent))
from grasp_probe import STATE, auc, placed_bins, rows_of, shifted  # noqa: E402
from taskrl.encoders import GlimpseInput, ImageStateInput  # noqa: E402
from taskrl.envs.grasp import SHAPES, GraspSettings  # noqa: E402
from taskrl.fused_q import PictureActionQ  # noqa: E402
from taskrl.nets import StateActionQ  # noqa: E402
from taskrl.types import PicturePose, PictureState  # noqa: E402

HIDDEN = (256, 256)


def labelled_closes(n: int, seed: int) -> tuple[PictureState, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(states [n], actions [n, 4], holds [n], the yaw decides [n])``: a closing action from a placed gripper, and
    whether its move ends over the spine of an object that fits at some yaws only (over no disc's centre): there the
    yaw decides whether it holds."""
    env, x, g = placed_bins(n, seed, 0.2)
    action = torch.rand(n, 4, generator=g) * 2 - 1
    action[:, 3] = 1.0  # close
    on_spine = env.hold_conditions(*env.moved(action))[0]
    yaw_decides = on_spine.any(1) & ~(on_spine & (env.shape == SHAPES.index("disc"))).any(1)
    _, _, _, _, info = env.step(action)
    return x, action, info["is_success"].float(), yaw_decides


class PostMoveYaw(nn.Module):
    """The flat join with the action extended by the gripper's yaw after the move (cos and sin of twice and four times
    it, from the state's cos and sin of twice the yaw and the action's turn): the form in which a jaw's fit depends
    on it (period 180 degrees for a bar, 90 for a square)."""

    def __init__(self) -> None:
        super().__init__()
        self.inner = StateActionQ(STATE + 64 * 64 * 3, 4 + 4, HIDDEN, ImageStateInput(STATE, (64, 64, 3), "conv", 50))
        self.max_turn = GraspSettings().max_turn

    def extended(self, vector: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        turn = 2 * self.max_turn * action[..., 2]
        c, s = vector[..., 2], vector[..., 3]  # cos, sin of twice the yaw
        c2, s2 = c * torch.cos(turn) - s * torch.sin(turn), s * torch.cos(turn) + c * torch.sin(turn)
        return torch.cat([action, torch.stack([c2, s2, c2 * c2 - s2 * s2, 2 * c2 * s2], -1)], -1)

    def forward(self, x: PictureState, action: torch.Tensor) -> torch.Tensor:
        return self.inner(x, self.extended(x.vector, action))

    def score_actions(self, x: PictureState, actions: torch.Tensor) -> torch.Tensor:
        return self.inner.score_actions(x, self.extended(x.vector[:, None], actions))


#: the grasp bin's gripper pose in the probe's (unnormalised) state vector: what `GlimpseInput` turns the picture by
POSE = PicturePose("observation", 0, 1, 2, 3, turns=2)


def network(fusion: str) -> nn.Module:
    if fusion == "glimpse":  # the flat join from the whole picture's features and a glimpse in the jaws' frame
        return StateActionQ(0, 4, HIDDEN, GlimpseInput(STATE, (64, 64, 3), "conv", 50, POSE))
    if fusion == "wide":  # the flat join from 256 picture features instead of 50
        return StateActionQ(STATE + 64 * 64 * 3, 4, HIDDEN, ImageStateInput(STATE, (64, 64, 3), "conv", 256))
    if fusion == "conv":
        return PictureActionQ(STATE, (64, 64, 3), 4, HIDDEN)
    if fusion == "yaw":
        return PostMoveYaw()
    return StateActionQ(STATE + 64 * 64 * 3, 4, HIDDEN, ImageStateInput(STATE, (64, 64, 3), "conv", 50))


def seconds_per_candidate(net: nn.Module, x: PictureState, repeats: int = 5) -> float:
    actions = torch.rand(64, 32, 4) * 2 - 1
    best = math.inf
    with torch.no_grad():
        for _ in range(repeats):
            start = time.perf_counter()
            net.score_actions(rows_of(x, slice(0, 64)), actions)
            best = min(best, time.perf_counter() - start)
    return best / (64 * 32)


def probe(fusion: str, pad: int, moved: bool, updates: int, train: tuple, test: tuple, seed: int, every: int = 1000) -> dict:
    torch.manual_seed(seed)
    net = network(fusion)
    optimiser = torch.optim.Adam(net.parameters(), 3e-4)
    (x, a, y, _), (x_test, a_test, y_test, yaw_decides) = train, test
    g = torch.Generator().manual_seed(seed)
    curve, start = [], time.perf_counter()
    for step in range(updates + 1):
        if step % every == 0:
            with torch.no_grad():
                score = torch.cat(
                    [net(rows_of(x_test, slice(i, i + 500)), a_test[i : i + 500]) for i in range(0, x_test.rows, 500)]
                )
            curve.append(
                {
                    "updates": step,
                    "auc": auc(score, y_test),
                    "yaw_auc": auc(score[yaw_decides], y_test[yaw_decides]),  # where only the yaw decides
                    "seconds": time.perf_counter() - start,
                }
            )
            print(fusion, pad, moved, curve[-1], flush=True)
        rows = torch.randint(x.rows, (64,), generator=g)
        logits = net(shifted(rows_of(x, rows), pad, g, moved), a[rows])
        loss = nn.functional.binary_cross_entropy_with_logits(logits, y[rows])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return {
        "fusion": fusion,
        "pad": pad,
        "moved": moved,
        "curve": curve,
        "ms_per_candidate": 1e3 * seconds_per_candidate(net, x_test),
    }


def probe_arm(job: tuple) -> dict:
    torch.set_num_threads(1)
    return probe(*job)


def pad_label(arm: dict) -> str:
    return f"{arm['pad']}, the gripper's x, y moved with it" if arm.get("moved") else f"{arm['pad']}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--arms",
        nargs="+",
        default=["flat:2", "conv:2"],
        help="FUSION:PAD, or FUSION:PAD:moved (the gripper's x, y moved with the picture)",
    )
    parser.add_argument("--updates", type=int, default=6000)
    parser.add_argument("--every", type=int, default=1000, help="updates between held-out scores")
    parser.add_argument("--train-states", type=int, default=40_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1, help="arms trained at once, one process and thread each")
    parser.add_argument("--write", action="store_true", help="replace the RESULTS section")
    parser.add_argument(
        "--title",
        default="Grasp critic probe: where the action meets the picture (label depends on the action)",
        help="the RESULTS section the arms answer (another question's arms go to their own section)",
    )
    parser.add_argument("--raw", default="grasp_fusion_probe.json", help="the raw data's file under benchmarks/results/")
    parser.add_argument("--report", action="store_true", help="train nothing: the section from the raw data")
    args = parser.parse_args()
    torch.set_num_threads(1)
    raw = Path(__file__).parent / "results" / args.raw
    if args.report:
        saved = json.loads(raw.read_text())
        share, results = saved["holding_share"], saved["arms"]
        args.workers = saved.get("workers", 1)
        curve = results[0]["curve"]  # the training's length and scoring interval, as it ran
        args.updates, args.every = curve[-1]["updates"], curve[1]["updates"] - curve[0]["updates"]
    else:
        train, test = labelled_closes(args.train_states, 1), labelled_closes(4_000, 2)
        jobs = [
            (arm[0], int(arm[1]), arm[2:] == ["moved"], args.updates, train, test, args.seed, args.every)
            for arm in (a.split(":") for a in args.arms)
        ]
        # one torch thread per arm; forked workers share the labelled closes
        with ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("fork")) as pool:
            results = list(pool.map(probe_arm, jobs))
        share = float(test[2].mean())
        raw.write_text(json.dumps({"holding_share": share, "workers": args.workers, "arms": results}, indent=2) + "\n")
    steps = [row["updates"] for row in results[0]["curve"]]
    lines = [
        f"{args.train_states:,} training closes, 4,000 held-out ones ({share:.0%} of them hold), arms "
        f"{', '.join(sorted({r['fusion'] for r in results}))}; batch 64, Adam 3e-4, "
        f"one torch thread, seed {args.seed}; the MLP after either join is 256 x 256. Held-out AUC (0.5: chance), and the "
        "time to score one candidate action when 64 states x 32 candidates are scored at once:",
        "",
        "| fusion | shift pad | " + " | ".join(f"{s:,}" for s in steps) + " | ms per candidate |",
        "|---|---|" + "---|" * len(steps) + "---|",
    ]
    for r in results:
        aucs = " | ".join(f"{row['auc']:.2f}" for row in r["curve"])
        lines.append(f"| {r['fusion']} | {pad_label(r)} | {aucs} | {r['ms_per_candidate']:.3f} |")
    if all("yaw_auc" in row for r in results for row in r["curve"]):
        lines += [
            "",
            "The same scores on the held-out closes whose move ends over the spine of a square, bar or ellipse (no "
            "disc), where only the yaw decides whether it holds (AUC; 0.5: the yaw not seen):",
            "",
            "| fusion | shift pad | " + " | ".join(f"{s:,}" for s in steps) + " |",
            "|---|---|" + "---|" * len(steps),
        ]
        for r in results:
            lines.append(
                f"| {r['fusion']} | {pad_label(r)} | " + " | ".join(f"{row['yaw_auc']:.2f}" for row in r["curve"]) + " |"
            )
    text = "\n".join(lines)
    print(text)
    if args.write:
        from common import append_results

        append_results(
            args.title,
            "Trained with `.venv/bin/python benchmarks/grasp_fusion_probe.py --arms "
            + " ".join(f"{r['fusion']}:{r['pad']}" + (":moved" if r.get("moved") else "") for r in results)
            + " --updates "
            f"{args.updates}{'' if args.every == 1000 else f' --every {args.every}'} --workers {args.workers}` (raw data: `benchmarks/results/{args.raw}`): "
            f"{args.workers} arm(s) at a time, one process and torch thread each, so the milliseconds compare the arms "
            "with each other, not with an idle machine.\n\n" + text,
        )


if __name__ == "__main__":
    main()
