"""The replay's memory per stored transition against Stable-Baselines3's ``HerReplayBuffer`` at equal capacity,
and its sample + hindsight-relabel time against the previous storage (two commits, side by side).

Tasks: bit flipping with n = 15 (episodes of 1-15 steps, as a learning run's end at success) and FetchReach
(episodes of 50 steps). Memory: every table a buffer allocates, divided by its capacity, after filling it
to capacity. Time: ``sample(256)`` then ``HindsightRelabeler("future", k=4)``, in child processes that
import taskrl from each commit's ``src``, alternated (before, after, before, ...), one torch thread.

    git worktree add /tmp/taskrl-before <commit of the previous storage>
    .venv/bin/python benchmarks/replay_memory.py --before /tmp/taskrl-before/src [--write]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

from common import append_results

CAPACITY = 100_000
SRC = str(Path(__file__).resolve().parents[1] / "src")

# Runs in a child process with one commit's taskrl first on the path; prints per-block microseconds per call.
CHILD = r"""
import inspect, json, sys, time
import gymnasium as gym, numpy as np, torch
torch.set_num_threads(1)
from taskrl.replay import EpisodeReplay, HindsightRelabeler
task, capacity, blocks, calls = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
if task == "bitflip15":
    n, horizon = 15, 15
    space = gym.spaces.Dict({k: gym.spaces.MultiBinary(n) for k in ("observation", "achieved_goal", "desired_goal")})
    actions = gym.spaces.Discrete(n)
    reward_fn = lambda a, d, info: -(a != d).any(-1).float()
else:
    horizon = 50
    box = lambda d: gym.spaces.Box(-np.inf, np.inf, (d,), np.float32)
    space = gym.spaces.Dict({"observation": box(10), "achieved_goal": box(3), "desired_goal": box(3)})
    actions = gym.spaces.Box(-1, 1, (4,), np.float32)
    reward_fn = lambda a, d, info: -((a - d).norm(dim=-1) > 0.05).float()
envs = 64
if "horizon" in inspect.signature(EpisodeReplay).parameters and list(inspect.signature(EpisodeReplay).parameters)[3] == "horizon":
    replay = EpisodeReplay(space, actions, capacity, horizon, envs)  # the horizon-row layout
else:
    replay = EpisodeReplay(space, actions, capacity, num_envs=envs, horizon=horizon)
g = torch.Generator().manual_seed(0)
def obs():
    if task == "bitflip15":
        return {k: torch.randint(0, 2, (envs, 15), generator=g, dtype=torch.int8) for k in space.spaces}
    return {k: torch.randn(envs, s.shape[0], generator=g) for k, s in space.spaces.items()}
lengths = torch.randint(1, horizon + 1, (envs,), generator=g) if task == "bitflip15" else torch.full((envs,), horizon)
t = torch.zeros(envs, dtype=torch.long)
replay.start(obs())
for _ in range(3 * capacity // envs):
    t += 1
    done = t >= lengths
    a = torch.randint(0, 15, (envs,), generator=g) if task == "bitflip15" else torch.rand(envs, 4, generator=g)
    o = obs()
    replay.add(a, torch.full((envs,), -1.0), done & (lengths < horizon), done & (lengths == horizon), o, o)
    t[done] = 0
    if task == "bitflip15":
        lengths = torch.where(done, torch.randint(1, horizon + 1, (envs,), generator=g), lengths)
her = HindsightRelabeler(reward_fn, "future", 4)
out = []
for _ in range(blocks):
    start = time.perf_counter()
    for _ in range(calls):
        her(replay.sample(256, g), replay, g)
    out.append((time.perf_counter() - start) / calls * 1e6)
print(json.dumps({"us": out, "stored": replay.num_transitions}))
"""


def child_timing(src: str, task: str, blocks: int, calls: int) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, task, str(CAPACITY), str(blocks), str(calls)],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": src, "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"},
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def nbytes(value) -> int:
    """Bytes of the numpy arrays and torch tensors in ``value`` (a dict, or an object's attributes)."""
    import torch

    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, torch.Tensor):
        return value.nbytes
    if isinstance(value, dict):
        return sum(nbytes(v) for v in value.values())
    return 0


def taskrl_bytes(task: str) -> tuple[float, int]:
    """taskrl's bytes per transition after filling to capacity (with its spaces), and episodes stored."""
    import gymnasium as gym
    import torch

    from taskrl.envs import BitFlip
    from taskrl.replay import EpisodeReplay

    if task == "bitflip15":
        env = BitFlip(15, num_envs=64)
        space, actions, horizon = env.single_observation_space, env.single_action_space, 15
    else:
        from taskrl.envs.gymnasium_adapter import GymnasiumGoalEnv

        with GymnasiumGoalEnv("FetchReach-v4", num_envs=1) as fetch:
            space, actions, horizon = fetch.single_observation_space, fetch.single_action_space, fetch.horizon
    replay = EpisodeReplay(space, actions, CAPACITY, num_envs=64, horizon=horizon)
    g = torch.Generator().manual_seed(0)

    def obs():
        return {
            k: torch.zeros((64, *s.shape), dtype=torch.from_numpy(np.zeros((), s.dtype)).dtype) for k, s in space.spaces.items()
        }

    lengths = torch.randint(1, horizon + 1, (64,), generator=g) if task == "bitflip15" else torch.full((64,), horizon)
    t = torch.zeros(64, dtype=torch.long)
    replay.start(obs())
    action = torch.zeros((64, *actions.shape))
    while replay.transitions_added < 2 * CAPACITY:
        t += 1
        done = t >= lengths
        replay.add(action, torch.zeros(64), done, torch.zeros(64, dtype=torch.bool), obs(), obs())
        t[done] = 0
        lengths = (
            torch.where(done, torch.randint(1, horizon + 1, (64,), generator=g), lengths) if task == "bitflip15" else lengths
        )
    assert isinstance(space, gym.spaces.Dict)
    tables = [replay.obs, replay.steps, replay._staging.obs, replay._staging.steps]
    total = sum(nbytes(t) for t in tables)
    total += sum(t.nbytes for t in (replay.step_episode, replay.episode_step_start, replay.episode_obs_start, replay.length))
    return total / CAPACITY, replay.num_episodes


def sb3_bytes(task: str) -> float:
    """Stable-Baselines3's ``HerReplayBuffer`` bytes per transition at the same capacity (its own env's spaces)."""
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.vec_env import DummyVecEnv

    if task == "bitflip15":
        from stable_baselines3.common.envs import BitFlippingEnv

        vec = DummyVecEnv([lambda: BitFlippingEnv(n_bits=15)])
    else:
        import gymnasium as gym
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)
        vec = DummyVecEnv([lambda: gym.make("FetchReach-v4")])
    buffer = HerReplayBuffer(CAPACITY, vec.observation_space, vec.action_space, env=vec, device="cpu")
    total = sum(nbytes(v) for v in vars(buffer).values())
    vec.close()
    return total / CAPACITY


RAW = Path(__file__).with_name("results") / "replay_memory_sampling.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", required=True, help="src folder of the previous storage's commit")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--blocks", type=int, default=5)
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    tasks = ("bitflip15", "fetchreach")

    memory_rows = []
    for task in tasks:
        ours, episodes = taskrl_bytes(task)
        theirs = sb3_bytes(task)
        memory_rows.append(f"| {task} | {CAPACITY:,} | {ours:.1f} | {theirs:.1f} | {theirs / ours:.2f}x | {episodes:,} |")

    timing = {task: {"before": [], "after": []} for task in tasks}
    stored = {}
    for _ in range(args.rounds):
        for task in tasks:
            for which, src in (("before", args.before), ("after", SRC)):
                got = child_timing(src, task, args.blocks, args.calls)
                timing[task][which] += got["us"]
                stored[(task, which)] = got["stored"]
    time_rows = []
    for task in tasks:
        before, after = statistics.median(timing[task]["before"]), statistics.median(timing[task]["after"])
        time_rows.append(
            f"| {task} | {stored[(task, 'before')]:,} | {stored[(task, 'after')]:,} | {before:.0f} | {after:.0f} | {after / before:.2f}x |"
        )
    before_commit = subprocess.run(
        ["git", "-C", args.before, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    body = (
        f"The previous storage: commit {before_commit or args.before}.\n\n"
        "Memory after filling each buffer to its capacity (`taskrl`: every tensor of the replay, its staging and "
        "episode slots; SB3 2.9.2 `HerReplayBuffer`: every array it allocates, `n_envs=1`). taskrl stores bits as "
        "int8 and Fetch's float64 observations as float32 (its adapter's default); SB3 keeps the env's dtypes "
        "(bits as int8 too, since its `BitFlippingEnv` is `MultiBinary`; Fetch float64), stores every next "
        "observation a second time, and 8-byte episode starts and lengths per transition.\n\n"
        "| task | capacity (transitions) | taskrl bytes / transition | SB3 bytes / transition | SB3 / taskrl | episodes stored |\n"
        "|---|---|---|---|---|---|\n" + "\n".join(memory_rows) + "\n\n"
        f"Sample 256 + hindsight relabelling (future, k = 4), microseconds per call: median of {args.rounds} rounds x "
        f"{args.blocks} blocks of {args.calls} calls, each commit in its own process, alternated. The previous storage "
        f"(one row of `horizon` steps per episode) holds fewer transitions at the same capacity on bit flipping, where "
        "episodes end early.\n\n"
        "| task | transitions stored before | after | before (us) | after (us) | after / before |\n"
        "|---|---|---|---|---|---|\n" + "\n".join(time_rows) + "\n\n"
        f"Raw per-block figures (us): `benchmarks/results/{RAW.name}`."
    )
    print(body)
    if args.write:
        RAW.write_text(json.dumps(timing, indent=1) + "\n")
        append_results("Replay memory and sampling: transitions counted against SB3 and the previous storage", body)


if __name__ == "__main__":
    main()
