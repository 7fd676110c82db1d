"""What a QT-Opt run's Q-function looks like on FetchPush-v4: bounds, twins, flatness, saturation, the block.

Loads a run's checkpoint, plays ``--episodes`` greedy episodes (the CEM argmax of the online network) and
measures on the transitions seen:

- ``q_above_0``: share of states where max_a Q(s, a) > 0 (every return is <= 0 with rewards in {-1, 0});
- ``target_above_0``: share of Bellman targets above 0 (0 by construction when targets are clipped);
- ``twin_gap``: mean |Q_target1(s', a*) - Q_target2(s', a*)| at the target's CEM action, beside ``mean_abs_q``;
- ``flatness``: mean max_a Q(s, a) - Q(s, a_taken) over the episodes' own (greedy) actions plus uniform
  random ones, i.e. how much the action matters to Q;
- ``greedy_at_bound``: share of greedy action components within 0.001 of a bound of the box;
- ``block_moved``: share of greedy episodes in which the block moves more than 1 cm;
- ``success``: share of greedy episodes that end with the block at the goal.

    .venv/bin/python benchmarks/qtopt_diagnose.py RUN_DIR [RUN_DIR ...] --episodes 20
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch


def diagnose(run_dir: Path, episodes: int, seed: int = 1234) -> dict:
    import gymnasium as gym
    import gymnasium_robotics  # noqa: F401  (registers Fetch)

    import taskrl
    from taskrl.replay.batch import Batch

    torch.set_num_threads(1)
    agent = taskrl.load(run_dir)
    env = gym.make("FetchPush-v4")
    rows: dict[str, list] = {k: [] for k in ("obs", "action", "reward", "next_obs")}
    moved, solved = [], []
    g = torch.Generator().manual_seed(seed)
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        start = obs["achieved_goal"].copy()
        for _ in range(50):
            action = agent.act(obs, generator=g)
            next_obs, reward, terminated, truncated, info = env.step(action)
            for key, value in (("obs", obs), ("action", action), ("reward", reward), ("next_obs", next_obs)):
                rows[key].append(value)
            obs = next_obs
            if terminated or truncated:
                break
        moved.append(float(np.linalg.norm(obs["achieved_goal"] - start) > 0.01))
        solved.append(float(info["is_success"]))
    env.close()

    def stack(dicts: list[dict]) -> dict[str, torch.Tensor]:
        return {k: torch.as_tensor(np.stack([d[k] for d in dicts]), dtype=torch.float32) for k in dicts[0]}

    n = len(rows["reward"])
    batch = Batch(
        obs=stack(rows["obs"]),
        action=torch.as_tensor(np.stack(rows["action"]), dtype=torch.float32),
        reward=torch.as_tensor(rows["reward"], dtype=torch.float32),
        next_obs=stack(rows["next_obs"]),
        terminated=torch.zeros(n, dtype=torch.bool),
        truncated=torch.zeros(n, dtype=torch.bool),
        episode=torch.zeros(n, dtype=torch.long),
        step=torch.zeros(n, dtype=torch.long),
    )
    with torch.no_grad():
        x, next_x = agent.inputs(batch.obs), agent.inputs(batch.next_obs)
        greedy, best = agent.argmax(agent.q, x, g)
        best_q = agent.q_value(best)
        taken = agent.q_value(agent.q(x, agent.box.to_unit(batch.action)))
        random = torch.rand(batch.action.shape, generator=g) * 2 - 1
        random_q = agent.q_value(agent.q(x, random))
        target = agent.bellman_target(batch, g)
        a_star, out1 = agent.argmax(agent.q_target1, next_x, g)
        out2 = agent.q_target2(next_x, a_star)
    return {
        "run": run_dir.name,
        "step": agent.loaded_step,
        "transitions": n,
        "q_above_0": (best_q > 0).float().mean().item(),
        "target_above_0": (target > 0).float().mean().item(),
        "twin_gap": (agent.q_value(out1) - agent.q_value(out2)).abs().mean().item(),
        "mean_abs_q": best_q.abs().mean().item(),
        "flatness": torch.cat([best_q - taken, best_q - random_q]).mean().item(),
        "greedy_at_bound": (greedy.abs() > 0.999).float().mean().item(),
        "block_moved": float(np.mean(moved)),
        "success": float(np.mean(solved)),
    }


def table(results: list[dict]) -> str:
    keys = ("q_above_0", "target_above_0", "twin_gap", "mean_abs_q", "flatness", "greedy_at_bound", "block_moved", "success")
    lines = ["| run | env step | " + " | ".join(keys) + " |", "|---|---|" + "---|" * len(keys)]
    for r in results:
        lines.append(f"| {r['run']} | {r['step']:,} | " + " | ".join(f"{r[k]:.3f}" for k in keys) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = parser.parse_args()
    results = [diagnose(run, args.episodes) for run in args.runs]
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    print(table(results))


if __name__ == "__main__":
    main()
