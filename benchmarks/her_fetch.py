"""taskrl against Stable-Baselines3: SAC + hindsight relabelling on FetchReach-v4.

Each library with its recommended settings for this env: SB3 with rl-baselines3-zoo's
hyperparameters for FetchReach (``hyperparams/sac.yml``: 1 env, one update per env step, gamma
0.95, lr 1e-3, batch 256, 64x64, future k = 4, 1000 learning-starts steps, ``normalize: True``,
i.e. ``VecNormalize`` of observations and rewards; ``--no-sb3-normalize`` leaves that out, as
this script did before); taskrl with its ``fetchreach-sac-her`` preset (2 envs, one update per two
env steps, gamma 0.98, lr 1e-3, batch 256, its own running observation normaliser) with
``--hidden-sizes 64 64``. These are not equal work: taskrl makes half the updates per env step. Both are evaluated every ``--eval-interval`` env
steps by taskrl's batched evaluator on the same 100 episodes (final-step ``is_success``, greedy
policy); evaluation time is excluded from both clocks. Reported: median wall-clock and env steps
to 90% success over seeds, and the ratio.

    .venv/bin/python benchmarks/her_fetch.py --seeds 0 1 2 --write
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from common import append_results, median_table, sb3_learn_until, taskrl_learn_until
from taskrl.envs import GymnasiumGoalEnv
from taskrl.training.evaluation import evaluate
from taskrl.wiring.parts import EVAL_SEED_OFFSET

ENV_ID = "FetchReach-v4"


def taskrl_time_to_success(seed: int, budget: int, eval_interval: int, target: float) -> dict:
    return taskrl_learn_until("fetchreach-sac-her", seed, budget, eval_interval, target, hidden_sizes=(64, 64))


def sb3_model(seed: int, normalize: bool = True):
    """``(model, venv)``: SB3's SAC + HER with the zoo's FetchReach settings (``normalize``: its VecNormalize)."""
    import gymnasium as gym
    import gymnasium_robotics
    from stable_baselines3 import SAC, HerReplayBuffer
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    gym.register_envs(gymnasium_robotics)
    venv = DummyVecEnv([lambda: gym.make(ENV_ID)])
    if normalize:  # the zoo's `normalize: True`: VecNormalize with its defaults and the run's gamma
        venv = VecNormalize(venv, gamma=0.95)
    model = SAC(
        "MultiInputPolicy",
        venv,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
        learning_rate=1e-3,
        batch_size=256,
        gamma=0.95,
        learning_starts=1000,
        buffer_size=int(1e6),
        policy_kwargs=dict(net_arch=[64, 64]),
        seed=seed,
        verbose=0,
    )
    return model, venv


def sb3_time_to_success(seed: int, budget: int, eval_interval: int, target: float, normalize: bool = True) -> dict:
    model, venv = sb3_model(seed, normalize)
    eval_seed = seed + EVAL_SEED_OFFSET
    eval_env = GymnasiumGoalEnv(ENV_ID, num_envs=100)

    def success(m) -> float:
        def act(obs):
            np_obs = {k: v.cpu().numpy() for k, v in obs.items()}
            if normalize:  # the policy was trained on normalised observations
                np_obs = venv.normalize_obs(np_obs)
            return torch.as_tensor(m.predict(np_obs, deterministic=True)[0])

        return evaluate(act, eval_env, eval_seed)["success_rate"]

    try:
        return sb3_learn_until(model, success, eval_interval, target, budget)
    finally:
        eval_env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--libs", nargs="+", default=["taskrl", "sb3"], choices=["taskrl", "sb3"])
    parser.add_argument("--budget", type=int, default=20_000)
    parser.add_argument("--eval-interval", type=int, default=1_000)
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for both libraries")
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    parser.add_argument(
        "--sb3-normalize",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="SB3 with the zoo's VecNormalize (its recommended setting for FetchReach)",
    )
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/her_fetch.json"), help="per-seed results")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    runners = {"taskrl": taskrl_time_to_success, "sb3": lambda *a: sb3_time_to_success(*a, normalize=args.sb3_normalize)}
    runs = []
    for lib in args.libs:
        for seed in args.seeds:
            r = runners[lib](seed, args.budget, args.eval_interval, args.target)
            r.update(lib=lib, seed=seed, key=ENV_ID, budget=args.budget)
            runs.append(r)
            print(json.dumps(r), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(runs, indent=2))
    table, _ = median_table(runs, [ENV_ID], args.libs, "env")
    print(table)
    if args.write:
        append_results(
            "SAC + hindsight relabelling vs Stable-Baselines3 (FetchReach-v4)",
            f"Seeds {args.seeds}, eval every {args.eval_interval} env steps on 100 fixed episodes, "
            f"torch threads = {args.threads} for both, evaluation excluded from both clocks.\n\n{table}",
        )


if __name__ == "__main__":
    main()
