"""Throughput of SAC on Meta-World v3 reach: taskrl against Stable-Baselines3, same network and batch.

Both libraries run SAC with a (256, 256) actor and critics, batch 256, lr 3e-4, gamma 0.99, on
Meta-World's ``reach-v3`` (MT1, goal resampled every episode, horizon 500), with ``--learning-starts``
random steps and then ``--steps`` env steps of learning. Reported: training env steps/s and
gradient updates/s of the learning phase only (random collection and evaluation excluded), for

- ``sb3``: ``SAC("MlpPolicy", gym.make("Meta-World/MT1", env_name="reach-v3"))``, one env, one update
  per env step (its default ``train_freq=1, gradient_steps=1``);
- ``taskrl 1 env``: one env, one update per env step (the same work as SB3);
- ``taskrl 10 envs``: ten copies stepped as one batch, still one update per env step;
- ``taskrl preset``: ``mt1-reach-sac`` as shipped (10 copies, 0.5 updates per env step).

    .venv/bin/python benchmarks/metaworld_sac.py --write
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

import taskrl
from common import append_results
from qtopt_cem import matmul_gflops
from taskrl.logger import read_metrics

TASK = "reach-v3"
OBS_DIM, ACTION_DIM = 39, 4


def sac_update_flops(batch: int, hidden: int) -> float:
    """Multiply-adds x 2 of one SAC update with two-layer networks of width ``hidden``.

    Actor forward Fa, critic forward Fc. Target: Fa + 2 Fc. Critic step: 2 x (Fc + 2 Fc backward).
    Actor step: Fa + 2 Fa backward, plus 2 critics forward and backward to the action only (~2 Fc
    each, critic weights frozen). Total 4 Fa + 12 Fc.
    """
    fa = 2 * batch * (OBS_DIM * hidden + hidden * hidden + hidden * 2 * ACTION_DIM)
    fc = 2 * batch * ((OBS_DIM + ACTION_DIM) * hidden + hidden * hidden + hidden)
    return 4 * fa + 12 * fc


def taskrl_throughput(num_envs: int, updates_per_step: float, learning_starts: int, steps: int, seed: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        taskrl.train(
            "mt1-reach-sac",
            out=out,
            seed=seed,
            num_envs=num_envs,
            updates_per_step=updates_per_step,
            hidden_sizes=(256, 256),
            batch_size=256,
            learning_starts=learning_starts,
            total_steps=learning_starts + steps,
            eval_interval=learning_starts,
            eval_episodes=1,
            tensorboard=False,
            checkpoint_interval=10**12,
            save_replay=False,
        )
        last = read_metrics(out / "metrics.csv")[-1]  # the row covering the learning phase only
    return {"env_steps_per_s": last["env_steps_per_s"], "updates_per_s": last["updates_per_s"]}


def sb3_throughput(learning_starts: int, steps: int, seed: int) -> dict:
    import gymnasium as gym
    import metaworld  # noqa: F401  (registers Meta-World/*)
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback

    env = gym.make("Meta-World/MT1", env_name=TASK, seed=seed)
    model = SAC(
        "MlpPolicy",
        env,
        learning_rate=3e-4,
        batch_size=256,
        gamma=0.99,
        learning_starts=learning_starts,
        buffer_size=1_000_000,
        policy_kwargs=dict(net_arch=[256, 256]),
        seed=seed,
        verbose=0,
    )
    marks: dict[str, float] = {}

    class Clock(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == learning_starts:
                marks["start"] = time.perf_counter()
            return True

    model.learn(total_timesteps=learning_starts + steps, callback=Clock())
    seconds = time.perf_counter() - marks["start"]
    env.close()
    return {"env_steps_per_s": steps / seconds, "updates_per_s": steps / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--learning-starts",
        type=int,
        default=5_000,
        help="random steps first; >= 10 x 500 so that 10 copies have finished episodes to learn from",
    )
    parser.add_argument("--steps", type=int, default=3_000, help="env steps of the learning phase that is timed")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for both libraries")
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    L, N = args.learning_starts, args.steps
    rows = {
        "sb3 (1 env, 1 update / env step)": sb3_throughput(L, N, args.seed),
        "taskrl (1 env, 1 update / env step)": taskrl_throughput(1, 1.0, L, N, args.seed),
        "taskrl (10 envs, 1 update / env step)": taskrl_throughput(10, 1.0, L, N, args.seed),
        "taskrl preset mt1-reach-sac (10 envs, 0.5 updates / env step)": taskrl_throughput(10, 0.5, L, N, args.seed),
    }
    base = rows["sb3 (1 env, 1 update / env step)"]
    lines = ["| run | env steps/s | updates/s | env steps/s ratio to SB3 | updates/s ratio to SB3 |", "|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['env_steps_per_s']:.0f} | {r['updates_per_s']:.0f} | "
            f"{r['env_steps_per_s'] / base['env_steps_per_s']:.2f}x | {r['updates_per_s'] / base['updates_per_s']:.2f}x |"
        )
    gflops = matmul_gflops()
    bound_ms = sac_update_flops(256, 256) / gflops / 1e6
    lines += [
        "",
        f"FLOP bound of one update (256x256, batch 256, {sac_update_flops(256, 256) / 1e6:.0f} MFLOP) at the measured "
        f"{gflops:.0f} GFLOP/s: {bound_ms:.1f} ms, i.e. at most {1e3 / bound_ms:.0f} updates/s on this core "
        f"({1e3 / bound_ms / base['updates_per_s']:.1f}x SB3's rate) with one update per env step.",
    ]
    table = "\n".join(lines)
    print(json.dumps(rows, indent=2))
    print(table)
    if args.write:
        append_results(
            "SAC throughput on Meta-World reach-v3 vs Stable-Baselines3",
            f"Actor and critics (256, 256), batch 256, torch threads = {args.threads} for both; {L} random steps "
            f"untimed, then {N} env steps of learning timed (evaluation excluded).\n\n{table}",
        )


if __name__ == "__main__":
    main()
