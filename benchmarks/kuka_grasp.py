"""KukaGrasp-v0 (the pybullet grasping benchmark of Quillen et al. 2018): what its cheaper settling changes, what
the random policy achieves and how fast grasps are collected, and QT-Opt's runs beside its controls.

    # the same drops settled both ways: object positions, steps, seconds, and random success from each
    .venv/bin/python benchmarks/kuka_grasp.py settle --drops 40 --episodes 100 --write
    # the authors' random policy on training and test objects with one process per core: success, grasps/s
    .venv/bin/python benchmarks/kuka_grasp.py random --episodes 200 --write
    # the lift stopped once the grasp has failed, against the full lift: the same outcomes, and the CPU it saves
    .venv/bin/python benchmarks/kuka_grasp.py lift --episodes 400 --write
    # the supervised control's data: the grasps of a collection run, every step labelled with its grasp's outcome
    .venv/bin/python benchmarks/kuka_grasp.py outcomes runs/kuka-random runs/kuka-outcomes
    # wall-clock collection speed: copies, and the next episode prepared ahead or reset in place
    .venv/bin/python benchmarks/kuka_grasp.py collect --arms 6:in-place 6 12:in-place 12 --minutes 3 --write
    # the protocol's table: QT-Opt offline on a collection, online from it, the supervised control, both splits
    # (--reuse: evaluations of unchanged runs taken over from the raw data before)
    .venv/bin/python benchmarks/kuka_grasp.py protocol --random runs/kuka-random --runs runs/kuka-offline-s0 \
        --online runs/kuka-online-s0 --supervised runs/kuka-supervised-s0 --episodes 100 \
        --reuse benchmarks/results/kuka_grasp_protocol.json --write
    # trained runs acting with other CEM searches (the preset's, a wider one, the benchmark's CEM actor)
    .venv/bin/python benchmarks/kuka_grasp.py search --runs runs/kuka-offline-s0 runs/kuka-offline-s1 --write
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch

from taskrl.envs.kuka_grasp import STEPS, KukaGraspEnv, KukaGraspSettings, KukaGraspVectorEnv, random_grasp_action

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def random_episode(env: KukaGraspEnv, generator: torch.Generator) -> tuple[float, dict]:
    """The rest of a reset episode acted by the authors' random policy: its last reward and info."""
    for _ in range(STEPS):
        _, reward, terminated, _, info = env.step(random_grasp_action(generator, 1)[0].numpy())
        if terminated:
            break
    return reward, info


def settle_check(drops: int, episodes: int, seed: int = 0, modes: tuple[str, ...] = ("rest", "staggered")) -> dict:
    """The same drops (objects and poses) settled each of ``modes`` way and the definition's (500 steps each): where the
    objects end against the definition's, the simulation steps and seconds, and the random policy's success from
    each's initial states with the CPU seconds of its whole episodes (reset included: what collection costs)."""
    modes = (*modes, "definition")
    envs = {mode: KukaGraspEnv(settle=mode) for mode in modes}
    gaps = {m: [] for m in modes}
    steps, seconds, heights = ({m: [] for m in modes} for _ in range(3))
    try:
        for k in range(drops):
            ends = {}
            for mode, env in envs.items():
                env.reset(seed=seed + k)  # the same objects for each
                env.np_random = np.random.default_rng(10_000 + k)  # the same drop poses for each
                start = time.process_time()
                steps[mode].append(env.settle_objects(env.drop_poses(), mode))
                seconds[mode].append(time.process_time() - start)
                ends[mode] = env.object_positions()
                heights[mode].extend(ends[mode][:, 2].tolist())
            for mode in modes:
                gaps[mode].extend(np.linalg.norm(ends[mode] - ends["definition"], axis=1).tolist())
        success, episode_cpu = {}, {}
        for mode, env in envs.items():
            generator, wins = torch.Generator().manual_seed(seed), 0.0
            start = time.process_time()
            for k in range(episodes):
                env.reset(seed=seed + 1_000 + k)
                wins += random_episode(env, generator)[0]
            episode_cpu[mode] = (time.process_time() - start) / episodes
            success[mode] = wins / episodes
    finally:
        for env in envs.values():
            env.close()
    return {
        "drops": drops,
        "episodes": episodes,
        "objects": len(gaps["definition"]),
        **{f"gap_mean_m_{m}": float(np.mean(gaps[m])) for m in modes},
        **{f"gap_p90_m_{m}": float(np.quantile(gaps[m], 0.9)) for m in modes},
        **{f"steps_{m}": float(np.mean(v)) for m, v in steps.items()},
        **{f"seconds_{m}": float(np.mean(v)) for m, v in seconds.items()},
        **{f"height_mean_{m}": float(np.mean(v)) for m, v in heights.items()},
        **{f"random_success_{m}": s for m, s in success.items()},
        **{f"episode_cpu_s_{m}": v for m, v in episode_cpu.items()},
    }


def _lift_job(job: tuple[int, int]) -> dict:
    """One process's share of `lift_check`: the same seeded random-grasp episodes with the full lift and with the lift
    stopped once the grasp has failed for certain; each attempt's outcome and failure step, each way's CPU seconds."""
    first, episodes = job
    torch.set_num_threads(1)
    found: dict = {"attempts": [], "cpu_s": {}, "rewards": {}}
    for lift in ("definition", "decided"):
        env, rewards = KukaGraspEnv(lift=lift), []
        start = time.process_time()
        try:
            for k in range(first, first + episodes):
                env.reset(seed=k)  # a fresh simulation: the same episode both ways
                reward, info = random_episode(env, torch.Generator().manual_seed(k))
                rewards.append(reward)
                if lift == "definition" and info["attempted"]:
                    found["attempts"].append({"outcome": bool(reward), "failed_at": info["lift_failed_at"]})
        finally:
            env.close()
        found["cpu_s"][lift], found["rewards"][lift] = time.process_time() - start, rewards
    return found


def lift_check(episodes: int, copies: int = 2) -> dict:
    """The authors' random grasps, each episode once with the definition's full lift (1,000 steps) and once with
    ``lift="decided"``, ``copies`` processes: in the full lift, where the failure became certain
    (`KukaGraspEnv.lift_failed`) against the outcome at its end; the episodes whose reward differs between the two; each
    way's CPU seconds per episode."""
    from concurrent.futures import ProcessPoolExecutor

    share = episodes // copies
    with ProcessPoolExecutor(max_workers=copies) as pool:
        parts = list(pool.map(_lift_job, [(k * share, share) for k in range(copies)]))
    attempts = [a for part in parts for a in part["attempts"]]
    successes = [a for a in attempts if a["outcome"]]
    failures = [a for a in attempts if not a["outcome"]]
    called = [a["failed_at"] for a in failures if a["failed_at"]]
    row: dict = {
        "episodes": share * copies,
        "attempts": len(attempts),
        "successes": len(successes),
        "successes_called_failed": sum(bool(a["failed_at"]) for a in successes),
        "failures": len(failures),
        "failures_called_failed": len(called),
        "failed_at_mean": float(np.mean(called)) if called else float("nan"),
        "failed_at_max": max(called, default=0),
        "rewards_differ": sum(
            a != b for part in parts for a, b in zip(part["rewards"]["definition"], part["rewards"]["decided"])
        ),
    }
    for lift in ("definition", "decided"):
        row[f"cpu_s_per_episode_{lift}"] = sum(part["cpu_s"][lift] for part in parts) / row["episodes"]
    return row


def random_policy(objects: str, episodes: int, copies: int = 2, seed: int = 0, lift: str = "decided") -> dict:
    """The authors' random policy on ``copies`` processes: success over ``episodes`` grasps, and grasps per second."""
    env = KukaGraspVectorEnv(KukaGraspSettings(objects=objects, lift=lift), num_envs=copies, seed=seed)
    try:
        obs = env.reset(seed=seed)
        start, ended, wins, steps = time.perf_counter(), 0, 0.0, 0
        while ended < episodes:
            obs, reward, terminated, truncated, _ = env.step(env.scripted_action(obs))
            done = terminated | truncated
            ended += int(done.sum())
            wins += float(reward[done].sum())
            steps += copies
        seconds = time.perf_counter() - start
    finally:
        env.close()
    return {
        "objects": objects,
        "lift": lift,
        "episodes": ended,
        "success": wins / ended,
        "grasps_per_s": ended / seconds,
        "steps": steps,
    }


def outcome_labelled(source: Path, out: Path) -> dict:
    """A copy of a run's stored grasps in which every step's reward is its episode's outcome (1 if the grasp at its
    end lifted an object): trained with ``--gamma 0`` on it, QT-Opt's network regresses Q(s, a) on the grasp
    outcome, the benchmark's supervised control (same network, same data, same CEM acting)."""
    import shutil

    from taskrl.checkpoint import checkpoint_step, latest_checkpoint, load_checkpoint, save_checkpoint
    from taskrl.replay.storage import ring_rows

    saved = load_checkpoint(source / "checkpoints", ("replay",))["replay"]
    capacity, tail, count, *_ = (int(x) for x in saved["rings"])
    slots = saved["length"].shape[0]
    ids = (torch.arange(count) + tail) % slots
    lengths = saved["length"][ids]
    rows = ring_rows(saved["episode_step_start"][ids], lengths, capacity)  # every step, episode after episode
    reward = saved["steps/reward"]
    outcome = reward[rows[torch.cumsum(lengths, 0) - 1]]
    reward[rows] = outcome.repeat_interleave(lengths)
    out.mkdir(parents=True, exist_ok=False)
    shutil.copy(source / "config.json", out / "config.json")
    save_checkpoint(out / "checkpoints", {"replay": saved}, checkpoint_step(latest_checkpoint(source / "checkpoints")))
    return {"episodes": count, "steps": int(lengths.sum()), "success": float(outcome.float().mean())}


def _evaluation_env(run_dir: Path, episodes: int, held_out: bool = False):
    """``(env, seed)``: the evaluation env ``taskrl eval RUN`` (``--held-out``) scores a run on, ``episodes`` copies at
    the run's evaluation seed (the same objects and initial states)."""
    import dataclasses

    from taskrl.config import load
    from taskrl.envs.registry import env_family
    from taskrl.wiring.parts import EVAL_SEED_OFFSET, make_env

    config = load(run_dir / "config.json")
    config = dataclasses.replace(config, evaluation=dataclasses.replace(config.evaluation, eval_episodes=episodes))
    if held_out:
        config = dataclasses.replace(config, env_settings=env_family(config.env).held_out(config.env_settings))
    seed = config.seed + EVAL_SEED_OFFSET
    return make_env(config, "cpu", seed=seed, evaluation=True), seed


def greedy_actions(run_dir: Path, episodes: int, steps: int = 5) -> dict:
    """What a trained run's greedy policy does where the data's policy moved down: over the first ``steps`` steps of
    ``episodes`` evaluation episodes (training objects, the run's evaluation seed), the mean ``dz`` and the share of
    actions with ``dz <= -0.9`` (the random policy's data: ``dz = -1`` in 9 steps of 10)."""
    from taskrl.loading import load as load_agent

    agent = load_agent(run_dir)
    env, seed = _evaluation_env(run_dir, episodes)
    try:
        obs, dz = env.reset(seed=seed), []
        for _ in range(steps):
            action = agent.act(obs)
            dz.append(action[:, 2])
            obs, *_ = env.step(action)
    finally:
        env.close()
    dz = torch.cat(dz)
    return {"run": str(run_dir), "mean_dz": float(dz.mean()), "down_share": float((dz <= -0.9).float().mean())}


def _last_row(run_dir: Path) -> dict:
    """The last row of a run's ``metrics.csv`` (its empty cells left out)."""
    from taskrl.logger import read_metrics

    rows = read_metrics(run_dir / "metrics.csv")
    return {k: v for k, v in rows[-1].items() if v is not None} if rows else {}


def random_on_evaluation_episodes(run_dir: Path, episodes: int, held_out: bool) -> dict:
    """The authors' random policy on the very episodes ``taskrl eval RUN`` scores a run on (the run's evaluation
    seed: the same objects and initial states), so that a gap between the splits can be told from the draw."""
    from taskrl.training.evaluation import evaluate

    env, seed = _evaluation_env(run_dir, episodes, held_out)
    try:
        return evaluate(env.scripted_action, env, seed)
    finally:
        env.close()


def _evaluation_job(job: tuple) -> tuple[tuple, dict]:
    """One measurement of the protocol, in a process of its own: ``("random", run, held_out)``, ``("actions", run)`` or
    ``("greedy", run, held_out)``."""
    from taskrl.loading import evaluate_run

    torch.set_num_threads(1)
    kind, run_dir, *held_out = job
    start = time.perf_counter()
    if kind == "random":
        result = random_on_evaluation_episodes(run_dir, EPISODES[0], held_out[0])
    elif kind == "actions":
        result = greedy_actions(run_dir, EPISODES[0])
    else:
        result = evaluate_run(run_dir, episodes=EPISODES[0], held_out=held_out[0])
    return job, {**result, "seconds": time.perf_counter() - start}


EPISODES = [50]  # the protocol's episodes per evaluation, set before the workers start


#: acting searches compared by ``search`` (CEM settings; the rest as the run trained): the preset's own, a wider one,
#: the benchmark's CEM actor (dql_grasping ``policies.CEMActorPolicy``: 64 samples x 3 rounds, 10 elites, starting at
#: "down" (0, 0, -1, 0) with std 0.5), and the wide search from "down"
SEARCHES = {
    "preset": {},
    "wide": {"samples": 256, "iterations": 3, "elites": 24, "first_samples": 0},
    "actor": {"samples": 64, "iterations": 3, "elites": 10, "init_std": 0.5, "init_mean": (0.0, 0.0, -1.0, 0.0)},
    "wide-down": {
        "samples": 256, "iterations": 3, "elites": 24, "first_samples": 0, "init_std": 0.5, "init_mean": (0.0, 0.0, -1.0, 0.0)
    },
}  # fmt: skip


def search_job(job: tuple) -> tuple[tuple, dict]:
    """``(run, held_out, search, episodes)``: ``taskrl eval RUN [--held-out] --cem ...`` with one of `SEARCHES` (the run's
    evaluation seed: the same episodes for every search), in a process of its own."""
    from taskrl.loading import evaluate_run

    torch.set_num_threads(1)
    run_dir, held_out, search, episodes = job
    start = time.perf_counter()
    result = evaluate_run(run_dir, episodes=episodes, held_out=held_out, cem=SEARCHES[search] or None)
    return job, {**result, "seconds": time.perf_counter() - start}


def _online_part(run_dir: Path) -> dict:
    """What an online run (``--init-from``) added to the offline run it started from: its env steps, the grasps it
    collected (its replay's episodes past the preloaded ones, read at its first evaluation), its training success
    (exploring), and the offline run's updates before its own."""
    from taskrl.logger import read_metrics

    rows = read_metrics(run_dir / "metrics.csv")
    config = json.loads((run_dir / "config.json").read_text())
    before = _last_row(Path(config["checkpoints"]["init_from"]))
    return {
        "online_env_steps": int(rows[-1]["env_steps"]),
        "online_grasps": int(rows[-1]["replay_episodes"] - rows[0]["replay_episodes"]),
        "online_train_success": rows[-1]["train_success"],
        "offline_updates": int(before.get("updates", 0)),
    }


def online_kind(kind: str, config: dict) -> str:
    """An online run's row kind: its update ratio and, where it has one, its on-policy window (``--recent-fraction``),
    so that runs which differ in either are pooled apart."""
    kind = f"{kind} at {config['updates_per_step']:.2f} updates per env step"
    window = config["replay"].get("recent_fraction", 0.0)
    if window > 0:
        kind += f", {window:.0%} of each batch from the {config['replay']['recent_episodes']:,} newest grasps"
    return kind


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def evaluated_weights(run_dir: Path) -> str:
    """The SHA-256 of the weights ``taskrl eval RUN`` loads (the latest checkpoint's ``agent.safetensors``): a row
    evaluated before is reused only for the same weights."""
    from taskrl.checkpoint import latest_checkpoint

    return _digest(latest_checkpoint(run_dir / "checkpoints") / "agent.safetensors")


#: a row's fields that come from evaluating it (the rest describe the run and are read again)
EVALUATED = ("mean_dz", "down_share", "train", "train_length", "train_eval_seconds", "test", "test_length", "test_eval_seconds")


def protocol(
    random_run: Path,
    runs: list[Path],
    supervised: list[Path],
    episodes: int,
    workers: int = 2,
    online: list[Path] = (),
    reuse: dict | None = None,
) -> dict:
    """Each run evaluated greedily on training and test objects (``taskrl eval RUN`` and ``--held-out``), beside the
    random policy's success while collecting (training objects) and on the same evaluation episodes; the
    evaluations run ``workers`` at a time (one process each: an evaluation env simulates in one process). ``online``:
    runs started from an offline run (``--init-from``) that collected with their policy. ``reuse``: an earlier
    protocol's raw data, whose evaluations are taken over (marked ``reused``) for a run whose weights and config are
    the same (`evaluated_weights`, the config's SHA-256) at the same episode count: evaluation is deterministic (the run's
    evaluation seed, seeded CEM draws), so evaluating again would repeat them."""
    from concurrent.futures import ProcessPoolExecutor

    EPISODES[0] = episodes
    groups = (("QT-Opt", runs), ("QT-Opt, then online", list(online)), ("supervised on outcomes (gamma 0)", supervised))
    first = (runs or list(online))[0]  # the evaluation episodes are the same for every run of one seed offset
    identity = {
        str(run_dir): {"config_sha256": _digest(run_dir / "config.json"), "weights_sha256": evaluated_weights(run_dir)}
        for _, group in groups
        for run_dir in group
    }
    kept, random_kept = reusable(identity, reuse, episodes, str(first))
    jobs = [] if random_kept is not None else [("random", first, False), ("random", first, True)]
    for _, group in groups:
        for run_dir in group:
            if str(run_dir) not in kept:
                jobs += [("actions", run_dir), ("greedy", run_dir, False), ("greedy", run_dir, True)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        done = dict(pool.map(_evaluation_job, jobs))
    same = {"kind": "random (on the evaluation episodes)", "seed": 0, "updates": 0, "random_of": str(first)}
    same["config_sha256"] = identity[str(first)]["config_sha256"]
    if ("random", first, False) in done:
        for split, held_out in (("train", False), ("test", True)):
            result = done[("random", first, held_out)]
            same[split], same[f"{split}_length"] = result["success_rate"], result["eval_length"]
    else:
        same.update({k: random_kept[k] for k in ("train", "train_length", "test", "test_length")}, reused=True)
    rows = [same]
    for kind, group in groups:
        for run_dir in group:
            config = json.loads((run_dir / "config.json").read_text())
            last = _last_row(run_dir)  # what the run did (a time limit may stop it before total_steps)
            online_run = kind == "QT-Opt, then online"
            row_kind = online_kind(kind, config) if online_run else kind
            row = {"run": str(run_dir), "kind": row_kind, "seed": config["seed"], "updates": int(last.get("updates", 0))}
            row["train_wall_seconds"] = last.get("wall_seconds")
            row.update(identity[str(run_dir)])
            if online_run:
                row.update(_online_part(run_dir))
            if str(run_dir) in kept:
                row.update({k: kept[str(run_dir)][k] for k in EVALUATED}, reused=True)
            else:
                row.update({k: v for k, v in done[("actions", run_dir)].items() if k in ("mean_dz", "down_share")})
                for split, held_out in (("train", False), ("test", True)):
                    result = done[("greedy", run_dir, held_out)]
                    row[split], row[f"{split}_length"] = result["success_rate"], result["eval_length"]
                    row[f"{split}_eval_seconds"] = result["seconds"]
            rows.append(row)
            print(row, flush=True)
    return {"collected": _last_row(random_run), "rows": rows, "episodes": episodes}


def pooled_line(rows: list[dict], episodes: int) -> str:
    """This measurement's trained rows (not those carried from an earlier one) pooled over seeds, per kind: the
    success over all their episodes, per split."""
    kinds = {}
    for r in rows:
        if "run" in r and "episodes" not in r:  # rows carried from an earlier measurement carry their own count
            kinds.setdefault(r["kind"], []).append(r)
    parts = []
    for kind, group in kinds.items():
        n = episodes * len(group)
        train, test = (float(np.mean([r[split] for r in group])) for split in ("train", "test"))
        parts.append(f"{kind}, {len(group)} seeds: {train:.3f} training / {test:.3f} test objects ({n} episodes each)")
    return "Pooled over seeds: " + "; ".join(parts) + "."


def reusable(identity: dict[str, dict], reuse: dict | None, episodes: int, first: str) -> tuple[dict, dict | None]:
    """What of an earlier protocol's raw data ``reuse`` stands for this one: ``({run: its earlier row}, the random
    row or None)``. A run's row stands where its config and weights digests (``identity[run]``) are the ones evaluated
    then, at the same episode count; the random policy's row where it was measured on the episodes of the same run
    ``first`` (the same config)."""
    if reuse is None or reuse.get("episodes") != episodes:
        return {}, None
    rows = reuse["rows"]
    earlier = {r["run"]: r for r in rows if "run" in r and "weights_sha256" in r}
    kept = {run: earlier[run] for run, same in identity.items() if run in earlier and _same(earlier[run], same)}
    random_row = next((r for r in rows if r.get("random_of") == first), None)
    if random_row is None or random_row.get("config_sha256") != identity[first]["config_sha256"]:
        random_row = None
    return kept, random_row


def _same(row: dict, identity: dict) -> bool:
    return all(row.get(key) == value for key, value in identity.items())


def _idle_and_total_ticks() -> tuple[int, int]:
    """The machine's idle and total CPU ticks since boot (``/proc/stat``)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return fields[3] + fields[4], sum(fields)


def collection_speed(arm: str, minutes: float, out: Path) -> dict:
    """Wall-clock speed of ``taskrl train kukagrasp-random`` for ``minutes`` with ``arm`` = ``COPIES`` or
    ``COPIES:in-place`` (``--no-reset-ahead``): grasps and env steps per second over the run's own clock, and how busy
    the machine's cores were meanwhile (``/proc/stat``)."""
    import subprocess
    import sys

    copies, _, how = arm.partition(":")
    run = out / arm.replace(":", "-")
    command = [sys.executable, "-m", "taskrl.cli", "train", "kukagrasp-random", "--out", str(run), "--num-envs", copies]
    command += ["--max-hours", f"{minutes / 60:.4f}", "--no-progress", *(["--no-reset-ahead"] if how == "in-place" else [])]
    idle, total = _idle_and_total_ticks()
    subprocess.run(command, check=True, capture_output=True)
    idle_after, total_after = _idle_and_total_ticks()
    last = _last_row(run)
    return {
        "arm": arm,
        "copies": int(copies),
        "reset_ahead": how != "in-place",
        "grasps": int(last["replay_episodes"]),
        "env_steps": int(last["env_steps"]),
        "seconds": float(last["wall_seconds"]),
        "grasps_per_s": last["replay_episodes"] / last["wall_seconds"],
        "busy_share": 1 - (idle_after - idle) / max(total_after - total, 1),
        "random_success": float(last["train_success"]),
    }


def _interval(p: float, n: int) -> str:
    half = 1.96 * (p * (1 - p) / max(n, 1)) ** 0.5
    return f"{p:.2f} ± {half:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    settle = sub.add_parser("settle")
    settle.add_argument("--drops", type=int, default=40)
    settle.add_argument("--episodes", type=int, default=100)
    rand = sub.add_parser("random")
    rand.add_argument("--episodes", type=int, default=200)
    rand.add_argument("--copies", type=int, default=2)
    rand.add_argument("--lift", choices=("decided", "definition"), default="decided")
    lift = sub.add_parser("lift", help="the lift stopped once the grasp has failed, against the full lift")
    lift.add_argument("--episodes", type=int, default=400)
    lift.add_argument("--copies", type=int, default=2)
    for p in (settle, rand, lift):
        p.add_argument("--write", action="store_true")
    proto = sub.add_parser("protocol", help="QT-Opt's runs and the controls on training and test objects")
    proto.add_argument("--random", type=Path, required=True, help="the collection run (kukagrasp-random)")
    proto.add_argument("--runs", type=Path, nargs="*", default=[], help="QT-Opt runs trained on its data")
    proto.add_argument("--online", type=Path, nargs="*", default=[], help="runs started from one of those (--init-from)")
    proto.add_argument("--supervised", type=Path, nargs="*", default=[], help="the supervised control's runs")
    proto.add_argument("--episodes", type=int, default=50)
    proto.add_argument("--workers", type=int, default=2, help="evaluations at a time (one process each)")
    proto.add_argument("--random-test", type=Path, default=RESULTS / "kuka_grasp_random.json")
    proto.add_argument(
        "--earlier",
        type=Path,
        help="an earlier protocol's JSON: its trained rows join the table, marked (the same evaluation episodes)",
    )
    proto.add_argument(
        "--earlier-label", default="earlier", help="how the earlier rows are marked (a row marked before keeps its mark)"
    )
    proto.add_argument(
        "--reuse",
        type=Path,
        help="an earlier protocol's JSON: the evaluations of runs whose weights and config are unchanged are taken over",
    )
    proto.add_argument("--note", default="", help="a line on how the runs were made (commands, commit, times)")
    proto.add_argument("--write", action="store_true")
    searches = sub.add_parser("search", help="trained runs acting with other CEM searches, on their evaluation episodes")
    searches.add_argument("--runs", type=Path, nargs="+", required=True)
    searches.add_argument("--searches", nargs="+", choices=list(SEARCHES), default=list(SEARCHES))
    searches.add_argument("--episodes", type=int, default=100)
    searches.add_argument("--workers", type=int, default=2)
    searches.add_argument("--note", default="", help="a line on how the runs were made (commands, commit, times)")
    searches.add_argument("--write", action="store_true")
    collect = sub.add_parser("collect", help="wall-clock speed of the random collection, copies and reset_ahead")
    collect.add_argument("--arms", nargs="+", default=["6:in-place", "6", "12:in-place", "12"], help="COPIES[:in-place]")
    collect.add_argument("--minutes", type=float, default=3.0, help="each arm's run")
    collect.add_argument("--out", type=Path, default=Path("/tmp/kuka_collect"))
    collect.add_argument("--write", action="store_true")
    outcomes = sub.add_parser("outcomes", help="the supervised control's data: a run's grasps labelled by their outcome")
    outcomes.add_argument("source", type=Path)
    outcomes.add_argument("out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    from common import append_results

    if args.what == "lift":
        row = lift_check(args.episodes, args.copies)
        print(json.dumps(row, indent=1))
        if args.write:
            (RESULTS / "kuka_grasp_lift.json").write_text(json.dumps(row, indent=1) + "\n")
            cpu = {m: row[f"cpu_s_per_episode_{m}"] for m in ("definition", "decided")}
            table = "\n".join(
                [
                    "| outcome of the full lift | attempts | called failed midway | lift step of the call: mean / max |",
                    "|---|---|---|---|",
                    f"| success | {row['successes']} | {row['successes_called_failed']} | - |",
                    f"| failure | {row['failures']} | {row['failures_called_failed']} | "
                    f"{row['failed_at_mean']:.0f} / {row['failed_at_max']} |",
                    "",
                    "| lift | CPU seconds per episode | grasps per second on 2 cores (2 / CPU seconds) |",
                    "|---|---|---|",
                    *(f"| {m} | {cpu[m]:.2f} | {2 / cpu[m]:.2f} |" for m in cpu),
                ]
            )
            append_results(
                "KukaGrasp: the lift stopped once the grasp has failed, against the full lift",
                f"{row['episodes']} episodes of the authors' random grasps on training objects ({row['attempts']} "
                f"attempts), each seeded episode played twice in {args.copies} processes: with the definition's full "
                f"close-and-lift (1,000 simulation steps), recording the lift step at which `lift=decided` would have "
                f"stopped (`KukaGraspEnv.lift_failed`: both fingers shut and no object touching the arm, checked every 10 "
                f"lift steps), and with `lift=decided`. Episodes whose reward differs between the two: "
                f"{row['rewards_differ']}. CPU seconds are each process's own (`time.process_time`), so they do not "
                f"depend on what else the machine ran; the grasps-per-second column is what 2 cores would give if "
                f"nothing else ran and the copies never waited for each other. Raw data: "
                f"`benchmarks/results/kuka_grasp_lift.json`.\n\n" + table,
            )
    elif args.what == "collect":
        import shutil

        shutil.rmtree(args.out, ignore_errors=True)
        rows = []
        for arm in args.arms:
            rows.append(collection_speed(arm, args.minutes, args.out))
            print(json.dumps(rows[-1]), flush=True)
        table = "\n".join(
            [
                "| copies (processes) | next episode | grasps | env steps | seconds | grasps per second | cores busy | "
                "random success |",
                "|---|---|---|---|---|---|---|---|",
                *(
                    f"| {r['copies']} | {'prepared ahead' if r['reset_ahead'] else 'reset in place'} | {r['grasps']:,} | "
                    f"{r['env_steps']:,} | {r['seconds']:.0f} | {r['grasps_per_s']:.2f} | {100 * r['busy_share']:.0f}% | "
                    f"{r['random_success']:.2f} |"
                    for r in rows
                ),
            ]
        )
        print(table)
        if args.write:
            (RESULTS / "kuka_grasp_collect.json").write_text(json.dumps(rows, indent=1) + "\n")
            append_results(
                "KukaGrasp: collection speed of the random grasps on 2 cores",
                f"`taskrl train kukagrasp-random` (the authors' random policy, staggered settling, the lift stopped once "
                f"failed, pictures stored) run for {args.minutes:g} minutes per row, one row after the other, nothing "
                f"else running; grasps are the episodes the replay holds at the end, over the run's own clock (`wall_seconds` "
                f"of its metrics: the training loop's; starting the processes is not counted). \"Prepared ahead\": each copy simulates its next episode's "
                f"initial state in a second simulation while it waits for the others (`reset_ahead`, the default); "
                f'"reset in place": `--no-reset-ahead`. Cores busy: the share of the 2 cores\' time not idle over the '
                f"row (`/proc/stat`). Raw data: `benchmarks/results/kuka_grasp_collect.json`.\n\n" + table,
            )
    elif args.what == "outcomes":
        print(outcome_labelled(args.source, args.out))
    elif args.what == "search":
        from concurrent.futures import ProcessPoolExecutor

        jobs = [(run, held, search, args.episodes) for run in args.runs for search in args.searches for held in (False, True)]
        rows = []
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            for (run, held, search, _), result in pool.map(search_job, jobs):
                row = {"run": str(run), "search": search, "split": "test" if held else "train"}
                row.update({k: result[k] for k in ("success_rate", "eval_length", "seconds")})
                print(json.dumps(row), flush=True)
                rows.append(row)
        found = {"searches": {name: SEARCHES[name] for name in args.searches}, "episodes": args.episodes, "rows": rows}
        cell = {(r["run"], r["search"], r["split"]): r for r in rows}
        lines = [
            "| run | search | training objects | test objects | steps per episode (training / test) |",
            "|---|---|---|---|---|",
        ]
        for run in map(str, args.runs):
            for search in args.searches:
                train, test = cell[run, search, "train"], cell[run, search, "test"]
                lines.append(
                    f"| {Path(run).name} | {search} | {_interval(train['success_rate'], args.episodes)} | "
                    f"{_interval(test['success_rate'], args.episodes)} | {train['eval_length']:.1f} / {test['eval_length']:.1f} |"
                )
        pooled = {
            search: np.mean([r["success_rate"] for r in rows if r["search"] == search and r["split"] == "test"])
            for search in args.searches
        }
        lines += ["", "Pooled over the runs, test objects: " + ", ".join(f"{k} {v:.2f}" for k, v in pooled.items()) + "."]
        text = "\n".join(lines)
        print(text)
        if args.write:
            (RESULTS / "kuka_grasp_search.json").write_text(json.dumps(found, indent=1) + "\n")
            described = "; ".join(
                f"{name}: " + (", ".join(f"{k} {v}" for k, v in SEARCHES[name].items()) or "the run's own CEM")
                for name in args.searches
            )
            append_results(
                "KukaGrasp: the trained runs acting with other CEM searches",
                f"Each run's greedy policy acting with CEM searches other than the one it trained and is scored with, on "
                f"the very evaluation episodes `taskrl eval RUN` (`--held-out`) scores it on (the run's evaluation seed: "
                f"the same objects and initial states, the same CEM draws for the same search), {args.episodes} "
                f"episodes per row and split; 95% normal intervals. The searches (`CEMConfig` fields changed): "
                f"{described}. {args.note} Raw data: `benchmarks/results/kuka_grasp_search.json`.\n\n" + text,
            )
    elif args.what == "protocol":
        reuse = json.loads(args.reuse.read_text()) if args.reuse else None
        found = protocol(args.random, args.runs, args.supervised, args.episodes, args.workers, args.online, reuse)
        if args.earlier:  # read before --write replaces it (it may be the same file)
            saved = json.loads(args.earlier.read_text())
            earlier = [r for r in saved["rows"] if r.get("updates", 0) > 0]
            label = f" ({args.earlier_label})" if args.earlier_label else ""  # "": the rows as they were marked
            # each carried row keeps the episodes it was scored on (its interval)
            found["rows"] += [
                {"episodes": saved.get("episodes", 50), **r, "kind": r["kind"] if r["kind"].endswith(")") else r["kind"] + label}
                for r in earlier
            ]
        random_rows = {r["objects"]: r for r in json.loads(args.random_test.read_text())} if args.random_test.exists() else {}
        grasps = int(found["collected"].get("replay_episodes", 0))
        lines = [
            "| policy | seed | updates | training objects | test objects | steps per episode (training / test) "
            "| greedy dz: mean / share at -1 |",
            "|---|---|---|---|---|---|---|",
            f"| random (the data: its own grasps while collecting) | 0 | 0 | "
            f"{_interval(found['collected'].get('train_success', float('nan')), grasps)} ({grasps:,} grasps) | "
            + (
                f"{_interval(random_rows['test']['success'], random_rows['test']['episodes'])} ({random_rows['test']['episodes']} grasps) |"
                if "test" in random_rows
                else "not measured |"
            )
            + " - | - |",
        ]
        for r in found["rows"]:
            updates = f"{r['offline_updates']:,} + {r['updates']:,}" if "offline_updates" in r else f"{r['updates']:,}"
            kind = r["kind"] + (
                f" ({r['online_grasps']:,} grasps, {r['online_env_steps']:,} env steps; exploring: {r['online_train_success']:.2f})"
                if "online_grasps" in r
                else ""
            )
            kind += " [evaluated before]" if r.get("reused") else ""
            lines.append(
                f"| {kind} | {r['seed']} | {updates} | {_interval(r['train'], r.get('episodes', args.episodes))} | "
                f"{_interval(r['test'], r.get('episodes', args.episodes))} | {r['train_length']:.1f} / {r['test_length']:.1f} | "
                + (f"{r['mean_dz']:.2f} / {r['down_share']:.2f} |" if "mean_dz" in r else "- |")
            )
        lines += ["", pooled_line(found["rows"][1:], args.episodes)]
        text = "\n".join(lines)
        print(text)
        if args.write:
            (RESULTS / "kuka_grasp_protocol.json").write_text(json.dumps(found, indent=1) + "\n")
            append_results(
                "KukaGrasp: QT-Opt offline on random grasps, on training and test objects",
                f"Greedy evaluation (CEM), {args.episodes} episodes per row and split (rows carried from an earlier "
                f"measurement: its own count), objects redrawn every episode; "
                f"95% normal intervals. Rows marked [evaluated before]: the same weights and config as in the raw "
                f"data before (SHA-256 of each), whose evaluation is deterministic, so it was taken over, not repeated. {args.note} Raw data: `benchmarks/results/kuka_grasp_protocol.json`.\n\n"
                + text,
            )
    elif args.what == "settle":
        row = settle_check(args.drops, args.episodes)
        print(json.dumps(row, indent=1))
        if args.write:
            (RESULTS / "kuka_grasp_settle.json").write_text(json.dumps(row, indent=1) + "\n")
            modes = ("definition", "rest", "staggered")
            table = "\n".join(
                [
                    "| settling | simulation steps per reset | CPU seconds per reset | objects' distance from the definition's "
                    "end: mean / 90th percentile (cm) | mean object height (m) | random success | CPU seconds per episode "
                    "| grasps per second on 2 cores |",
                    "|---|---|---|---|---|---|---|---|",
                    *(
                        f"| {m} | {row[f'steps_{m}']:.0f} | {row[f'seconds_{m}']:.2f} | "
                        + (
                            "- | "
                            if m == "definition"
                            else f"{100 * row[f'gap_mean_m_{m}']:.1f} / {100 * row[f'gap_p90_m_{m}']:.1f} | "
                        )
                        + f"{row[f'height_mean_{m}']:.3f} | {_interval(row[f'random_success_{m}'], row['episodes'])} | "
                        f"{row[f'episode_cpu_s_{m}']:.2f} | {2 / row[f'episode_cpu_s_{m}']:.2f} |"
                        for m in modes
                    ),
                ]
            )
            append_results(
                "KukaGrasp: settling until at rest against the definition's 500 steps",
                f"{args.drops} drops of 5 training objects, the same objects and drop poses settled each way; where the "
                f"{row['objects']} objects end is compared with the definition's. Random policy success: the authors' "
                f"random grasps, {args.episodes} episodes each from the same seeds (the same objects, and the same drop "
                f"poses), 95% interval; the CPU seconds of those episodes, reset included, are each process's own "
                f"(`time.process_time`), so they do not depend on what else the machine ran, and the last column is what 2 "
                f"cores would give if the copies never waited for each other. Raw data: "
                f"`benchmarks/results/kuka_grasp_settle.json`.\n\n" + table,
            )
    else:
        rows = [random_policy(objects, args.episodes, args.copies, lift=args.lift) for objects in ("train", "test")]
        for row in rows:
            print(row, flush=True)
        if args.write:
            (RESULTS / "kuka_grasp_random.json").write_text(json.dumps(rows, indent=1) + "\n")
            table = "\n".join(
                [
                    "| objects | episodes | success (95% interval) | grasps per second |",
                    "|---|---|---|---|",
                    *(
                        f"| {r['objects']} | {r['episodes']} | {_interval(r['success'], r['episodes'])} | {r['grasps_per_s']:.2f} |"
                        for r in rows
                    ),
                ]
            )
            append_results(
                "KukaGrasp: the random policy and collection speed",
                f"The authors' random policy (uniform actions, moving down 9 times in 10), objects redrawn every "
                f"episode, settling until at rest, {args.copies} processes (one per core), seed 0. The paper's "
                f"random-policy data grasp at about 0.4 (measured by running the authors' code). Raw data: "
                f"`benchmarks/results/kuka_grasp_random.json`.\n\n" + table,
            )


if __name__ == "__main__":
    main()
