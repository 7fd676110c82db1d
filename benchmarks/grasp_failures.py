"""Why a trained grasp policy's attempts fail: each greedy attempt on the native bin sorted by what the close missed.

An attempt ends in one of four ways: it holds; it closes with its centre over no object's spine (a miss of position);
it closes over a spine but at a yaw at which that object does not fit between the jaws (a miss of yaw); or it never
closes within the horizon. For a miss of position, how far the gripper's centre was from the nearest object's spine,
in pixels of the 64x64 picture (the hold's tolerance is 0.06 of the bin, 3.8 pixels). The attempts are those `taskrl
eval RUN` (``--held-out``) scores: the run's evaluation seed, seeded CEM draws.

    .venv/bin/python benchmarks/grasp_failures.py /work/runs-bench/grasp/fair-bin-seed0 ... --episodes 500 --write
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from taskrl.envs.grasp import SHAPES, SIZES, Grasp

HERE = Path(__file__).resolve().parent
OUTCOMES = ("held", "position", "yaw", "no close")


class _Sorting:
    """Wraps the evaluation env: before each step, how each copy's close (if it closes) would end."""

    def __init__(self, env: Grasp) -> None:
        self.env, self.num_envs, self.device, self.horizon = env, env.num_envs, env.device, env.horizon
        self.outcome = torch.full((env.num_envs,), -1, dtype=torch.long)  # index into OUTCOMES; -1 while running
        self.miss_pixels: list[float] = []
        self.yaw_misses: list[tuple[int, float]] = []  # (shape id, degrees to the nearest yaw at which it fits)
        # (shape id, held, share of yaws that fit, half-length) per close
        self.closed_over: list[tuple[int, bool, float, float]] = []

    def reset(self, seed: int | None = None):
        self.outcome.fill_(-1)
        return self.env.reset(seed=seed)

    def step(self, action: torch.Tensor):
        env = self.env
        action = action.reshape(self.num_envs, 4).clamp(-1, 1)
        gripper, yaw = env.moved(action)  # where the close is checked
        on_spine, fits = env.hold_conditions(gripper, yaw)
        closing = (action[:, 3] > 0) & (self.outcome < 0)
        kind = torch.where((on_spine & fits).any(1), 0, torch.where(on_spine.any(1), 2, 1))
        missed = closing & (kind == 1)
        self.miss_pixels += (_spine_distance(env, gripper)[missed] * env.settings.image_size).tolist()
        over_spine = closing & (kind != 1)
        if bool(over_spine.any()):
            # the object closed over: the one held, else the nearest whose spine the gripper is over
            distance = (gripper[:, None] - env.centre).norm(dim=-1)
            over = distance.masked_fill(~on_spine, torch.inf).masked_fill(
                (on_spine & fits).any(1, keepdim=True) & ~fits, torch.inf
            )
            rows = torch.nonzero(over_spine)[:, 0]
            target = over[rows].argmin(1)
            shape, half_length = env.shape[rows, target], env.half[rows, target, 0]
            yaw_error, fitting_share = _degrees_to_fitting_yaw(env, rows, target, yaw[rows])
            for j, i in enumerate(rows.tolist()):
                self.closed_over.append((int(shape[j]), bool(kind[i] == 0), float(fitting_share[j]), float(half_length[j])))
                if kind[i] == 2:
                    self.yaw_misses.append((int(shape[j]), float(yaw_error[j])))
        self.outcome = torch.where(closing, kind, self.outcome)
        result = env.step(action)
        last = (env.t == 0) & (self.outcome < 0)  # reset after its last step without a close
        self.outcome = torch.where(last, 3, self.outcome)
        return result


def _degrees_to_fitting_yaw(
    env: Grasp, rows: torch.Tensor, target: torch.Tensor, yaw: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``([R], [R])`` for bins ``rows``: how far ``yaw`` is, in degrees, from the nearest yaw (on a 0.5-degree grid) at
    which object ``target`` fits between the jaws; and the share of the grid's yaws at which it fits (a close at a
    uniformly random yaw holds it that often)."""
    grid = torch.arange(0, 180, 0.5)
    fitting = []
    for degrees in grid.tolist():
        turned = torch.full_like(env.yaw, degrees * torch.pi / 180)
        fitting.append(env.hold_conditions(yaw=turned)[1][rows, target])
    fitting = torch.stack(fitting, 1)  # [R, grid]
    apart = (grid[None] - yaw[:, None] * 180 / torch.pi).abs() % 180
    apart = torch.minimum(apart, 180 - apart)  # a jaw turned by 180 degrees is the same jaw
    return apart.masked_fill(~fitting, torch.inf).min(1).values, fitting.float().mean(1)


def _spine_distance(env: Grasp, gripper: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``gripper``'s distance from the nearest object's spine (a segment; a disc's is its centre)."""
    along, across = env.spine_offsets(gripper)
    length, width = env.half.unbind(-1)
    beyond = (along - (length - width).clamp(min=0)).clamp(min=0)
    return torch.sqrt(beyond**2 + across**2).min(1).values


def _by_size(closed_over: list[tuple[int, bool, float, float]], shape_id: int, name: str) -> dict:
    """The closes over one shape's spine split at the middle of its sampled half-lengths (`SIZES`): the larger half
    of the squares fits within fewer degrees of face on."""
    low, high = SIZES[name][0]
    middle = (low + high) / 2
    halves = {}
    for label, smaller in ((f"{low:g}-{middle:g}", True), (f"{middle:g}-{high:g}", False)):
        part = [(held, share) for shape, held, share, half in closed_over if shape == shape_id and (half < middle) == smaller]
        if part:
            halves[label] = {
                "closes_over_spine": len(part),
                "held": sum(h for h, _ in part) / len(part),
                "held_at_random_yaw": sum(s for _, s in part) / len(part),
            }
    return halves


def sort_attempts(run_dir: Path, episodes: int, held_out: bool) -> dict:
    """The greedy attempts of ``run_dir``'s latest checkpoint on ``episodes`` bins, sorted into `OUTCOMES`."""
    from taskrl.config import load
    from taskrl.envs.registry import env_family
    from taskrl.loading import load as load_agent
    from taskrl.training.evaluation import ActingPolicy, evaluate
    from taskrl.wiring.parts import EVAL_SEED_OFFSET, make_env

    config = load(run_dir / "config.json")
    config = dataclasses.replace(config, evaluation=dataclasses.replace(config.evaluation, eval_episodes=episodes))
    if held_out:
        config = dataclasses.replace(config, env_settings=env_family(config.env).held_out(config.env_settings))
    seed = config.seed + EVAL_SEED_OFFSET
    env = _Sorting(make_env(config, "cpu", seed=seed, evaluation=True))
    scored = evaluate(ActingPolicy(load_agent(run_dir)), env, seed)  # greedy, its CEM draws seeded as `taskrl eval`'s
    counts = {name: int((env.outcome == i).sum()) for i, name in enumerate(OUTCOMES)}
    assert counts["held"] == round(scored["success_rate"] * episodes), "the sorting disagrees with the env's reward"
    miss = torch.tensor(env.miss_pixels) if env.miss_pixels else torch.zeros(0)
    tolerance_pixels = config.env_settings.tolerance * config.env_settings.image_size
    by_shape = {}
    for shape_id, name in enumerate(SHAPES):
        closes = [held for shape, held, _, _ in env.closed_over if shape == shape_id]
        by_chance = [share for shape, _, share, _ in env.closed_over if shape == shape_id]
        errors = torch.tensor([e for shape, e in env.yaw_misses if shape == shape_id])
        if closes:
            by_shape[name] = {
                "closes_over_spine": len(closes),
                "held": sum(closes) / len(closes),
                "held_at_random_yaw": sum(by_chance) / len(by_chance),
                "yaw_miss_degrees_median": float(errors.median()) if len(errors) else None,
                "by_size": _by_size(env.closed_over, shape_id, name),
            }
    return {
        "run": str(run_dir),
        "objects": "held out" if held_out else "training",
        "episodes": episodes,
        **{name: n / episodes for name, n in counts.items()},
        "position_miss_pixels_median": float(miss.median()) if len(miss) else None,
        "position_miss_within_2_more_pixels": float((miss <= 2 + tolerance_pixels).float().mean()) if len(miss) else None,
        "by_shape": by_shape,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--note", default="")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = [sort_attempts(run, args.episodes, held) for run in args.runs for held in (False, True)]
    lines = [
        "| run | objects | held | closed off every spine (position) | closed over a spine at a wrong yaw | never closed | "
        "position misses: median pixels from the nearest spine / share within 2 pixels of the tolerance |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        miss = (
            f"{r['position_miss_pixels_median']:.1f} / {r['position_miss_within_2_more_pixels']:.2f}"
            if r["position_miss_pixels_median"] is not None
            else "-"
        )
        lines.append(
            f"| {Path(r['run']).name} | {r['objects']} | {r['held']:.2f} | {r['position']:.2f} | {r['yaw']:.2f} | "
            f"{r['no close']:.2f} | {miss} |"
        )
    lines += [
        "",
        "Closes over an object's spine, by the object's shape (the one held, else the nearest under the gripper):",
        "",
        "| run | objects | shape | closes over its spine | held | held at a uniformly random yaw (the same closes) | "
        "misses of yaw: median degrees from a yaw that fits |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for shape, c in r["by_shape"].items():
            degrees = f"{c['yaw_miss_degrees_median']:.1f}" if c["yaw_miss_degrees_median"] is not None else "-"
            lines.append(
                f"| {Path(r['run']).name} | {r['objects']} | {shape} | {c['closes_over_spine']} | {c['held']:.2f} | "
                f"{c['held_at_random_yaw']:.2f} | {degrees} |"
            )
    lines += [
        "",
        "The same closes split at the middle of each shape's sampled half-lengths (the discs left out: they fit at any yaw):",
        "",
        "| run | objects | shape | half-length | closes over its spine | held | held at a uniformly random yaw |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for shape, c in r["by_shape"].items():
            if shape == "disc":
                continue
            for size, part in c.get("by_size", {}).items():
                lines.append(
                    f"| {Path(r['run']).name} | {r['objects']} | {shape} | {size} | {part['closes_over_spine']} | "
                    f"{part['held']:.2f} | {part['held_at_random_yaw']:.2f} |"
                )
    text = "\n".join(lines)
    print(text)
    if args.write:
        from common import append_results

        (HERE / "results" / "grasp_failures.json").write_text(json.dumps(rows, indent=1) + "\n")
        append_results(
            "Grasp from pixels: why the fair bin's greedy attempts fail",
            f"Each run's latest checkpoint acting greedily on {args.episodes} bins per row (the run's evaluation seed, "
            f"as `taskrl eval RUN` and `--held-out` score it), each attempt sorted by how it ended: held; closed with the "
            f"gripper's centre over no object's spine (position: farther than the 0.06 tolerance, 3.8 pixels, from every "
            f"spine); closed over a spine at a yaw at which that object does not fit between the jaws; or never closed "
            f"in the 8 steps. {args.note} Raw data: `benchmarks/results/grasp_failures.json`.\n\n" + text,
        )


if __name__ == "__main__":
    main()
