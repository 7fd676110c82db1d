"""``taskrl demos collect``: run each task's scripted expert, keep its successful episodes, write a dataset.

All tasks run at once (``copies`` env slots per task). The expert's action is recorded as the label;
with ``noise_std > 0`` Gaussian noise is added to the action that is *executed* (DART, Laskey et al.,
2017), so the states visited include small mistakes and the recorded labels show how to recover.
An episode counts when it succeeds by the source's criterion; a task whose expert keeps failing
stops after ``max_attempts`` episodes and the card says how many it has.

Resumable: finished episodes go to ``OUT/parts/part-NNNNN.npz`` (numpy arrays only, written
atomically) every ``flush_seconds``; running the same command again reads the parts, collects only
what is missing and then writes the Minari dataset (``OUT/data``) and removes the parts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.demos.dataset import Episode, check_new_dataset_folder, dataset_card, write_dataset
from taskrl.demos.experts import DemoSource, demo_source
from taskrl.errors import ConfigError

__all__ = ["collect_demos"]

PARTS = "parts"
SETTINGS_FILE = "collection.json"


def _read_parts(folder: Path) -> list[Episode]:
    episodes = []
    for part in sorted(folder.glob("part-*.npz")):
        with np.load(part, allow_pickle=False) as z:
            lengths = z["lengths"]
            o_at = np.concatenate([[0], np.cumsum(lengths + 1)])
            a_at = np.concatenate([[0], np.cumsum(lengths)])
            for i, name in enumerate(z["tasks"].tolist()):
                episodes.append(
                    Episode(
                        str(name),
                        z["observations"][o_at[i] : o_at[i + 1]],
                        z["actions"][a_at[i] : a_at[i + 1]],
                        z["rewards"][a_at[i] : a_at[i + 1]],
                        z["success"][a_at[i] : a_at[i + 1]],
                        bool(z["terminated"][i]),
                        z["images"][o_at[i] : o_at[i + 1]] if "images" in z else None,
                    )
                )
    return episodes


def _write_part(folder: Path, number: int, episodes: list[Episode]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"part-{number:05d}.npz"
    tmp = folder / f".part-{number:05d}.tmp.npz"
    pictures = {"images": np.concatenate([e.images for e in episodes])} if episodes[0].images is not None else {}
    np.savez(
        tmp,
        **pictures,
        tasks=np.array([e.task for e in episodes]),
        lengths=np.array([len(e) for e in episodes], dtype=np.int64),
        observations=np.concatenate([e.observations for e in episodes]).astype(np.float32),
        actions=np.concatenate([e.actions for e in episodes]).astype(np.float32),
        rewards=np.concatenate([e.rewards for e in episodes]).astype(np.float32),
        success=np.concatenate([e.success for e in episodes]).astype(bool),
        terminated=np.array([e.terminated for e in episodes], dtype=bool),
    )
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _check_settings(out: Path, settings: dict[str, Any]) -> None:
    """A folder resumed with other settings would mix two datasets: refuse in one line."""
    path = out / SETTINGS_FILE
    if path.exists():
        try:
            saved = json.loads(path.read_text())
        except (OSError, ValueError):
            saved = None
        if saved != settings:
            changed = sorted(k for k in settings if not isinstance(saved, dict) or saved.get(k) != settings[k])
            raise ConfigError(
                "out",
                f"{out} holds a collection with other settings ({', '.join(changed) or 'unreadable'}); "
                f"resume it with the same ones or choose another --out",
            )
    else:
        out.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(settings, indent=2) + "\n")


def collect_demos(
    source: str | DemoSource,
    episodes: int,
    out: str | Path,
    *,
    seed: int = 1,
    noise_std: float = 0.0,
    copies: int = 1,
    max_attempts: int = 0,
    after_success: int = 10,
    pictures: int = 0,
    flush_seconds: float = 30.0,
    progress: Callable[[int, int], Any] | None = None,
) -> dict[str, Any]:
    """Collect ``episodes`` successful demonstrations of every task of ``source`` into ``out``; returns the card.

    Args:
        source: ``mt10``, ``mt50``, ``ml45``, ``pointreach-mt``, Meta-World names separated by commas, or a
            `DemoSource`.
        episodes: successful episodes to keep per task.
        out: dataset folder (``out/data`` is the Minari dataset).
        seed: seed of the goal positions, the goal draws and the action noise (evaluation of a
            run uses its own seed: the default 1 keeps demonstrations' goals apart from seed 0's).
        noise_std: standard deviation of the Gaussian noise on executed actions (0: none).
        copies: env slots per task.
        max_attempts: episodes a task may try before it stops short (0: ``5 * episodes``).
        after_success: Meta-World: steps recorded after the first success before the episode ends.
        pictures: record each state's rendered picture at this size too (``image``; sources whose env renders,
            Meta-World's); 0: none. A source with its own camera (``tabletop``) always records it, at this size
            where given.
        flush_seconds: how often finished episodes are saved (what an interruption can lose).
        progress: ``(kept, wanted)`` after every step.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1 (got {episodes!r})")
    if not isinstance(noise_std, (int, float)) or not 0 <= noise_std <= 1:
        raise ConfigError("noise_std", f"must be in [0, 1] (got {noise_std!r})")
    if isinstance(copies, bool) or not isinstance(copies, int) or copies < 1:
        raise ConfigError("copies", f"must be an integer >= 1 (got {copies!r})")
    if isinstance(max_attempts, bool) or not isinstance(max_attempts, int) or max_attempts < 0:
        raise ConfigError("max_attempts", f"must be an integer >= 0 (got {max_attempts!r})")
    if isinstance(after_success, bool) or not isinstance(after_success, int) or after_success < 0:
        raise ConfigError("after_success", f"must be an integer >= 0 (got {after_success!r})")
    if isinstance(pictures, bool) or not isinstance(pictures, int) or not (pictures == 0 or 16 <= pictures <= 512):
        raise ConfigError("pictures", f"must be 0 (none) or a picture size in 16..512 pixels (got {pictures!r})")
    src = demo_source(source) if isinstance(source, str) else source
    if pictures and not src.cameras:
        raise ConfigError(
            "pictures", f"{src.name} cannot render pictures of its states; sources that can: Meta-World's, tabletop"
        )
    out = check_new_dataset_folder(out)
    max_attempts = max_attempts or 5 * episodes
    settings = {
        "source": src.name,
        "episodes": episodes,
        "seed": seed,
        "noise_std": float(noise_std),
        "copies": copies,
        "after_success": after_success,
        **({"pictures": pictures} if pictures else {}),
    }
    _check_settings(out, settings)
    parts = out / PARTS
    kept = _read_parts(parts) if parts.exists() else []
    have = {t.name: 0 for t in src.task_set}
    for e in kept:
        have[e.task] += 1
    attempts_file = parts / "attempts.json"
    attempts = {**dict.fromkeys(have, 0), **(json.loads(attempts_file.read_text()) if attempts_file.exists() else {})}
    number = len(list(parts.glob("part-*.npz"))) if parts.exists() else 0
    started = time.perf_counter()
    missing = [n for n in have if have[n] < episodes and attempts[n] < max_attempts]
    if missing:
        tally = _Tally(kept, have, attempts, parts, number)
        _run(
            src,
            missing,
            tally,
            copies,
            seed + 7919 * number,
            after_success,
            episodes,
            max_attempts,
            noise_std,
            flush_seconds,
            progress,
            pictures,
        )
    by_task = {t.name: [e for e in kept if e.task == t.name][:episodes] for t in src.task_set}
    chosen = [e for t in src.task_set for e in by_task[t.name]]
    if not chosen:
        raise RuntimeError(f"no expert episode of {src.name} succeeded in {max_attempts} attempts per task")
    card = {
        "source": src.name,
        "expert": "scripted",
        "episodes_per_task": {n: len(v) for n, v in by_task.items()},
        "expert_success_rate": {n: have[n] / max(attempts[n], 1) for n in have},
        "attempts": attempts,
        "success": f"reached at any step (episodes end {after_success} steps after the first success)"
        if src.success == "any"
        else "at the final step",
        "after_success": after_success if src.success == "any" else 0,
        "seed": seed,
        "noise_std": float(noise_std),
        "mean_length": {n: float(np.mean([len(e) for e in v])) if v else 0.0 for n, v in by_task.items()},
        "collection_seconds": round(time.perf_counter() - started, 1),
        **({"pictures": f"{pictures}x{pictures} rendered, beside the state"} if pictures else {}),
        **({"splits": src.splits} if src.splits else {}),
    }
    # every source's experts act in [-1, 1] (Meta-World's and PointReach's action box)
    action_space = gym.spaces.Box(-1.0, 1.0, shape=chosen[0].actions.shape[1:], dtype=np.float32)
    write_dataset(
        out,
        chosen,
        [(t.name, t.description) for t in src.task_set],
        action_space,
        card,
        f"taskrl/{src.name.replace(',', '+')}-demos-v0",
    )
    shutil.rmtree(parts, ignore_errors=True)
    (out / SETTINGS_FILE).unlink(missing_ok=True)
    return dataset_card(out)


@dataclasses.dataclass
class _Tally:
    """What a collection has so far: its episodes, successes and attempts per task, and its saved parts."""

    kept: list[Episode]
    have: dict[str, int]
    attempts: dict[str, int]
    parts: Path
    number: int  # parts written


def _run(src, names, tally, copies, seed, after_success, episodes, max_attempts, noise_std, flush_seconds, progress, pictures):
    """Run the experts of ``names`` until each has ``episodes`` successes or ``max_attempts`` tries."""
    kept, have, attempts, parts = tally.kept, tally.have, tally.attempts, tally.parts
    wanted = episodes * len(src.task_set)
    env = src.make_env(names, copies, seed, after_success, **({"image_size": pictures} if pictures else {}))
    try:
        expert = src.expert(env)
        generator = torch.Generator(device=env.device)
        generator.manual_seed(seed)
        slot_names = [env.task_set.names[int(t)] for t in env.slot_tasks.tolist()]
        n = env.num_envs
        obs = env.reset(seed=seed)
        record: list[dict[str, list]] = [{"o": [], "a": [], "r": [], "s": [], "i": []} for _ in range(n)]
        camera = "image" in obs
        pending: list[Episode] = []
        last_flush = time.monotonic()

        def flush() -> None:
            nonlocal pending, last_flush
            if pending:
                _write_part(parts, tally.number, pending)
                tally.number += 1
                pending = []
            (parts / "attempts.json").write_text(json.dumps(attempts))
            last_flush = time.monotonic()

        parts.mkdir(parents=True, exist_ok=True)
        try:
            while any(have[m] < episodes and attempts[m] < max_attempts for m in names):
                label = expert(obs)
                action = label
                if noise_std > 0:
                    noise = torch.randn(label.shape, generator=generator, device=label.device) * noise_std
                    action = (label + noise).clamp(-1.0, 1.0)
                next_obs, reward, terminated, truncated, info = env.step(action)
                states = obs["observation"].detach().cpu().numpy()
                labels, rewards = label.detach().cpu().numpy(), reward.detach().cpu().numpy()
                success = info["is_success"].detach().cpu().numpy().astype(bool)
                ended = (terminated | truncated).detach().cpu().numpy()
                final = info["final_obs"]["observation"].detach().cpu().numpy()
                if camera:  # the camera's pictures of the same steps
                    images, final_images = obs["image"].cpu().numpy(), info["final_obs"]["image"].cpu().numpy()
                term = terminated.detach().cpu().numpy()
                for s in range(n):
                    r = record[s]
                    r["o"].append(states[s]), r["a"].append(labels[s]), r["r"].append(rewards[s]), r["s"].append(success[s])
                    if camera:
                        r["i"].append(images[s])
                    if not ended[s]:
                        continue
                    task = slot_names[s]
                    ok = bool(r["s"][-1]) if src.success == "final" else bool(np.any(r["s"]))
                    if have[task] < episodes and attempts[task] < max_attempts:
                        attempts[task] += 1
                        if ok:
                            episode = Episode(
                                task,
                                np.stack([*r["o"], final[s]]),
                                np.stack(r["a"]),
                                np.asarray(r["r"], dtype=np.float32),
                                np.asarray(r["s"], dtype=bool),
                                bool(term[s]),
                                np.stack([*r["i"], final_images[s]]) if camera else None,
                            )
                            kept.append(episode), pending.append(episode)
                            have[task] += 1
                    record[s] = {"o": [], "a": [], "r": [], "s": [], "i": []}
                obs = next_obs
                if progress is not None:
                    progress(sum(min(v, episodes) for v in have.values()), wanted)
                if time.monotonic() - last_flush >= flush_seconds:
                    flush()
        finally:
            flush()  # what finished is kept, whatever stopped the loop
    finally:
        env.close()
