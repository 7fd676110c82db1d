"""How well can any policy choose the yaw of a grasp from the fair bin's picture? An upper bound per shape.

A grasp holds a square, a bar or an ellipse only within a window of yaws (``Grasp.hold_conditions``): for the larger
squares the sampled sizes allow a few degrees either side of face on. What the camera shows of an object's angle is
the set of pixels its shape covers (``taskrl.envs.grasp.covers``: a pixel is the object's when its centre is inside the shape,
no blending). For each object drawn as the env draws it (its shape's sizes, a uniform angle, a centre anywhere in a
pixel) this script renders it alone at 720 angles (every 0.25 degree of the half turn) with the same size, at its
own centre and at 9 x 9 centres within half a pixel of it, and keeps the (angle, centre) pairs whose picture is the
true one's (the fewest differing pixels, zero when the grid holds such a pair). A policy that reads only that
picture, knowing the object's size and (first bound) its exact centre or (second) its centre to within half a
pixel, can do no better than close at the yaw that holds for the most of those pairs' angles: each bound is the
mean, over objects, of that best share (the Bayes-optimal hold with the gripper on the spine, uniform priors).
Beside them: a uniformly random yaw's share; that some yaw holds each object is checked. The real observation tells
less (the size and centre unknown, the picture shifted, the gripper and other objects in it), so a policy's hold
rate on closes over the spine stays under the bounds.

    .venv/bin/python benchmarks/grasp_yaw_visibility.py --objects 300 --image-sizes 64 --write
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402
from taskrl.envs.grasp import SHAPES, SIZES, GraspSettings, covers, fits_between_jaws  # noqa: E402

TITLE = "Grasp env: how much of an object's yaw the picture shows (an upper bound on choosing the yaw)"
ANGLES = 720  # every 0.25 degree of the half turn (a parallel jaw is the same turned by pi)
GRID = torch.arange(ANGLES) * (math.pi / ANGLES)
#: the shapes whose hold depends on the yaw, and the size buckets reported for each (half-length edges)
BUCKETS = {"square": (0.052, 0.0585, 0.065), "bar": (0.08, 0.10, 0.12), "ellipse": (0.075, 0.0875, 0.10)}


def draw(shape: str, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``n`` objects of ``shape`` as the env draws them: half-sizes ``[n, 2]``, angles ``[n]``, centres ``[n, 2]``
    (anywhere within a pixel of the middle of the bin: only the sub-pixel offset matters to the picture)."""
    (lo, hi), width = SIZES[shape]
    length = lo + (hi - lo) * torch.rand(n, generator=generator)
    w = length if width is None else width[0] + (width[1] - width[0]) * torch.rand(n, generator=generator)
    angle = math.pi * torch.rand(n, generator=generator)
    centre = 0.5 + 0.05 * torch.rand(n, 2, generator=generator)
    return torch.stack([length, w], -1), angle, centre


def pictures(size: int, half: torch.Tensor, angle: torch.Tensor, centre: torch.Tensor, shape: str, around: torch.Tensor):
    """``[b, W * W]`` bool: the pixels each object covers (the camera's own test, `covers`) in the window of pixels
    around the point ``around`` that holds every candidate (the rest of the picture is floor for all of them)."""
    reach = int(math.ceil(float(half.norm(dim=-1).max()) * size)) + 2
    first = torch.floor(around * size).long() - reach
    pixels = torch.arange(2 * reach + 1)
    x = ((first[0] + pixels).float() + 0.5) / size
    y = ((first[1] + pixels).float() + 0.5) / size
    ellipse = torch.full((len(angle),), is_ellipse(shape))
    return covers(x[None, None, :], y[None, :, None], centre, angle, half, ellipse).flatten(1)


def fits(opening: float, half: torch.Tensor, turn: torch.Tensor, shape: str) -> torch.Tensor:
    """Whether the object fits between the open jaws when the closing direction is ``turn`` off its long axis
    (`Grasp.hold_conditions`' second condition)."""
    return fits_between_jaws(half, turn, is_ellipse(shape), opening)


def is_ellipse(shape: str) -> bool:
    """Drawn as an ellipse (a disc or an ellipse), as the env's camera and hold read its shape ids."""
    return SHAPES.index(shape) in (0, 3)


def best_share(opening: float, half: torch.Tensor, angles: torch.Tensor, shape: str) -> float:
    """The most that one yaw holds of objects at ``angles`` (equally likely given the picture)."""
    return float(fits(opening, half, GRID[:, None] - angles[None, :], shape).float().mean(1).max())


def bound(shape: str, image_size: int, objects: int, seed: int, offsets: int = 9, chunk: int = 4096) -> list[dict]:
    """Per object: its half-length, the random yaw's hold share, and the best share a policy reading the picture gets
    knowing the object's size and either its exact centre or its centre to within half a pixel (``offsets`` x
    ``offsets`` candidate centres, a uniform prior over them and the angles)."""
    opening = GraspSettings().opening
    generator = torch.Generator().manual_seed(seed)
    step = torch.linspace(-0.5, 0.5, offsets) / image_size
    shifts = torch.stack(torch.meshgrid(step, step, indexing="ij"), -1).reshape(-1, 2)  # [offsets^2, 2], (0, 0) in it
    angles = GRID.repeat(len(shifts))  # [offsets^2 * ANGLES]: every angle at each candidate centre
    rows = []
    for half, angle, centre in zip(*draw(shape, objects, generator)):
        truth = pictures(image_size, half[None], angle[None], centre[None], shape, centre)
        centres = (centre + shifts).repeat_interleave(ANGLES, 0)
        differing = torch.cat(
            [
                (pictures(image_size, half.expand(len(a), 2), a, c, shape, centre) != truth).sum(1)
                for a, c in zip(angles.split(chunk), centres.split(chunk))
            ]
        )
        at_centre = differing.view(len(shifts), ANGLES)[len(shifts) // 2]  # the true centre: the middle shift
        known = GRID[at_centre == at_centre.min()]
        near = differing == differing.min()  # the (angle, centre) pairs the picture cannot tell from the truth
        holds_at = fits(opening, half, GRID - angle, shape)  # each yaw of the grid against the true angle
        rows.append(
            {
                "half_length": float(half[0]),
                "random_yaw": float(holds_at.float().mean()),
                "best_centre_known": best_share(opening, half, known, shape),
                "best_centre_within_half_pixel": best_share(opening, half, angles[near], shape),
                "some_yaw_fits": bool(holds_at.any()),
                "blind_degrees_centre_known": float(len(known) * 180 / ANGLES),
            }
        )
    return rows


def mean(rows: list[dict], key: str) -> float:
    return sum(row[key] for row in rows) / len(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", type=int, default=2000, help="objects drawn per shape and picture size")
    parser.add_argument("--image-sizes", type=int, nargs="+", default=[64])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write", action="store_true", help="replace this section of benchmarks/RESULTS.md")
    args = parser.parse_args()
    torch.set_num_threads(1)
    raw = {f"{shape}@{size}": bound(shape, size, args.objects, args.seed) for size in args.image_sizes for shape in BUCKETS}
    lines = [
        f"{args.objects:,} objects per shape and picture size (seed {args.seed}), each rendered alone at {ANGLES} angles "
        "(0.25 degree apart) with its own size and centre; hold shares with the gripper on the spine. `random yaw`: "
        "the share of yaws that hold; `best, centre known` and `best, centre within half a pixel`: the two bounds (the "
        "script's docstring); `blind degrees, centre known`: the median width of the angles whose picture is the true "
        "one's at the true centre. Raw data: "
        "`benchmarks/results/grasp_yaw_visibility.json`.",
        "",
        "| picture | shape | half-length | objects | random yaw | best, centre known | best, centre within half a pixel "
        "| blind degrees, centre known |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for key, rows in raw.items():
        shape, size = key.split("@")
        assert all(row["some_yaw_fits"] for row in rows)  # the check: some yaw holds every object drawn
        edges = BUCKETS[shape]
        for lo, hi in [(edges[0], edges[-1]), *zip(edges, edges[1:])]:
            part = [row for row in rows if lo <= row["half_length"] <= hi]
            blind = sorted(row["blind_degrees_centre_known"] for row in part)
            lines.append(
                f"| {size}x{size} | {shape} | {lo}-{hi} | {len(part):,} | "
                f"{mean(part, 'random_yaw'):.3f} | "
                f"{mean(part, 'best_centre_known'):.3f} | {mean(part, 'best_centre_within_half_pixel'):.3f} | "
                f"{blind[len(blind) // 2]:.2f} |"
            )
    table = "\n".join(lines)
    print(table)
    out = Path(__file__).parent / "results" / "grasp_yaw_visibility.json"
    out.write_text(json.dumps(raw) + "\n")
    if args.write:
        append_results(TITLE, table)


if __name__ == "__main__":
    main()
