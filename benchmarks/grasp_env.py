"""The grasp env's costs and its success detector, on one torch thread.

- camera frames per second at 64x64 for a batch of bins (``Grasp.render``), and env steps per second;
- bytes of one stored picture (uint8, as the replay holds it) against float32;
- the detector's precision and recall against the simulator's holds, over attempts of a scripted
  grasper that closes over an object at a random yaw (so both outcomes occur), per object set;
- the scripted grasp's success (``Grasp.scripted_action``, the explorer of ``--scripted-exploration``) at
  several aim noises (``--part scripted``: that section alone, which times nothing).

    .venv/bin/python benchmarks/grasp_env.py --write
    .venv/bin/python benchmarks/grasp_env.py --part scripted --write
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent


def frames_per_second(batch: int, size: int, repeats: int) -> tuple[float, float]:
    from taskrl.envs.grasp import Grasp, GraspSettings

    env = Grasp(GraspSettings(image_size=size), num_envs=batch, seed=0)
    env.reset(seed=0)
    env.render()
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        env.render()
        best = min(best, time.perf_counter() - start)
    action = torch.rand(batch, 4) * 2 - 1
    action[:, 3] = -1  # move and turn; an episode ends at the horizon
    env.step(action)
    start = time.perf_counter()
    for _ in range(repeats):
        env.step(action)
    step = (time.perf_counter() - start) / repeats
    return batch / best, batch / step


def detector(objects: str, attempts: int, seed: int) -> dict:
    from taskrl.envs.grasp import Grasp, GraspSettings

    env = Grasp(GraspSettings(objects=objects), num_envs=attempts, seed=seed)
    env.reset(seed=seed)
    g = torch.Generator().manual_seed(seed)
    env.gripper = env.centre[:, 0] + 0.01 * torch.randn(attempts, 2, generator=g)
    env.yaw = math.pi * torch.rand(attempts, generator=g)
    close = torch.zeros(attempts, 4)
    close[:, 3] = 1
    _, _, _, _, info = env.step(close)
    held, detected = info["is_success"], info["detected"]
    tp = int((held & detected).sum())
    return {
        "objects": objects,
        "attempts": attempts,
        "held": int(held.sum()),
        "precision": tp / max(int(detected.sum()), 1),
        "recall": tp / max(int(held.sum()), 1),
        "false_positives": int((~held & detected).sum()),
        "false_negatives": int((held & ~detected).sum()),
    }


def scripted_success(aim_noise: float, bins: int, seed: int) -> dict:
    """Share of the scripted grasp's finished attempts that hold, 40 env steps on ``bins`` bins."""
    from taskrl.envs.grasp import Grasp, GraspSettings, scripted_attempts

    attempts, held = scripted_attempts(Grasp(GraspSettings(), num_envs=bins, seed=seed), aim_noise=aim_noise, seed=seed)
    return {"aim_noise": aim_noise, "seed": seed, "attempts": attempts, "held": held, "success": held / attempts}


def write_scripted(bins: int, write: bool) -> None:
    noises = (0.0, 0.04, 0.06, 0.08, 0.1)
    rows = [scripted_success(noise, bins, seed) for noise in noises for seed in (0, 1, 2)]
    lines = ["| aim noise | seed 0 | seed 1 | seed 2 | attempts (seed 0) |", "|---|---|---|---|---|"]
    for noise in noises:
        mine = [r for r in rows if r["aim_noise"] == noise]
        lines.append(f"| {noise} | " + " | ".join(f"{r['success']:.2f}" for r in mine) + f" | {mine[0]['attempts']:,} |")
    text = "\n".join(lines)
    print(text)
    (HERE / "results" / "grasp_scripted.json").write_text(json.dumps(rows, indent=2))
    if write:
        from common import append_results

        append_results(
            "Grasp env: the scripted grasp's success by aim noise",
            f"`Grasp.scripted_action(obs, aim_noise=...)` on {bins} bins for 40 env steps (default objects, 64x64): it "
            "is told where the objects are and aims off by a normal offset of `aim_noise` per axis and of aim_noise / 0.04 "
            "x 15 degrees in yaw; share of finished attempts that hold. `--scripted-exploration` uses 0.08. "
            "QT-Opt's scripted policy held in 15-30% of its attempts.\n\n" + text,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--attempts", type=int, default=4096)
    parser.add_argument("--bins", type=int, default=500, help="bins of the scripted grasp's measurement")
    parser.add_argument("--part", choices=("all", "scripted"), default="all")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    write_scripted(args.bins, args.write)
    if args.part == "scripted":
        return
    speed = [(b, *frames_per_second(b, 64, args.repeats)) for b in args.batches]
    found = [detector(objects, args.attempts, seed) for objects in ("train", "held_out") for seed in (0, 1, 2)]
    lines = ["| bins at once | camera frames/s | env steps/s (two pictures a step) |", "|---|---|---|"]
    lines += [f"| {b:,} | {fps:,.0f} | {sps:,.0f} |" for b, fps, sps in speed]
    lines += [
        "",
        "| objects | seed | attempts | held | precision | recall | false + | false - |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for seed, r in zip((0, 1, 2) * 2, found):
        lines.append(
            f"| {r['objects']} | {seed} | {r['attempts']:,} | {r['held']:,} | {r['precision']:.4f} | {r['recall']:.4f} | "
            f"{r['false_positives']} | {r['false_negatives']} |"
        )
    text = "\n".join(lines)
    print(text)
    (HERE / "results" / "grasp_env.json").write_text(json.dumps({"speed": speed, "detector": found}, indent=2))
    if args.write:
        from common import append_results

        append_results(
            "Grasp env: camera speed and the success detector",
            "One torch thread. A 64x64 picture is 12,288 bytes as the replay stores it (uint8), 49,152 as float32. "
            "Frames/s: the best of the repeats of `Grasp.render` for the whole batch; a step renders the picture after "
            "the step and, where an episode ended, the next episode's first one. Detector: one attempt per bin by a "
            "scripted grasper that closes within 0.01 of an object's centre at a random yaw, so some attempts hold "
            "and some do not; precision and recall of `detect_grasp` against the simulator's holds.\n\n" + text,
        )


if __name__ == "__main__":
    main()
