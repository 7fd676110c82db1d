"""taskrl against Stable-Baselines3: DQN + hindsight relabelling on random-goal bit flipping.

Both libraries train on the identical task: taskrl's bit flipping with a random start and a
random target every episode (SB3 runs it through the gymnasium registration
``taskrl/BitFlip-v0``, so its HerReplayBuffer calls the same ``compute_reward``). Both are
evaluated by the same function on the same 100 evaluation episodes every ``--eval-interval``
environment steps, with the greedy policy; evaluation time is excluded from both clocks.

SB3 uses the settings of its HER learning test for 2.9.x as recorded in the project's
REFERENCES (2 envs, lr 2e-3, batch 32, 64x64 network, train_freq 1, gradient_steps = n_envs,
target update every 100 steps; learning_starts 100), goal strategy ``future`` with k = 4, and
the same exploration length as taskrl: epsilon decays linearly to 0.05 over the first 20k env
steps (SB3 starts it at 1.0, taskrl at 0.5). taskrl uses its ``bitflip-her`` preset.

Reported: median wall-clock and env steps to 90% success over seeds, and the ratio; raw
training throughput (env steps/s) and gradient updates/s at equal batch size and network.

    .venv/bin/python benchmarks/her_bitflip.py --n-bits 15 20 25 --seeds 0 1 2 --write
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

import taskrl
from common import append_results, median_table, sb3_learn_until, taskrl_learn_until
from taskrl.envs import BitFlip
from taskrl.training.evaluation import evaluate
from taskrl.wiring.parts import EVAL_SEED_OFFSET


def taskrl_time_to_success(n_bits: int, seed: int, budget: int, eval_interval: int, target: float) -> dict:
    return taskrl_learn_until("bitflip-her", seed, budget, eval_interval, target, n_bits=n_bits)


def sb3_model(n_bits: int, seed: int, budget: int, batch_size: int = 32, net_arch=(64, 64), own_env: bool = False):
    """SB3's DQN + HER at the settings of its HER test. ``own_env``: step SB3's own ``BitFlippingEnv`` (numpy,
    its goal fixed at all ones), as a user's SB3 script would, instead of taskrl's random-goal env."""
    import gymnasium as gym
    from stable_baselines3 import DQN, HerReplayBuffer
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.envs import BitFlippingEnv

    n_envs = 2
    if own_env:
        make = lambda: BitFlippingEnv(n_bits=n_bits, continuous=False, max_steps=n_bits)
    else:
        make = lambda: gym.make("taskrl/BitFlip-v0", n_bits=n_bits)
    env = make_vec_env(make, n_envs=n_envs, seed=seed)
    return DQN(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future"),
        learning_rate=2e-3,
        train_freq=1,
        gradient_steps=n_envs,
        learning_starts=100,
        exploration_final_eps=0.05,
        exploration_fraction=min(1.0, 20_000 / budget),
        target_update_interval=100,
        batch_size=batch_size,
        buffer_size=int(1e5),
        policy_kwargs=dict(net_arch=list(net_arch)),
        seed=seed,
        verbose=0,
    )


def sb3_policy(model):
    def act(obs):
        np_obs = {k: v.cpu().numpy() for k, v in obs.items()}
        return torch.as_tensor(model.predict(np_obs, deterministic=True)[0])

    return act


def sb3_time_to_success(n_bits: int, seed: int, budget: int, eval_interval: int, target: float) -> dict:
    model = sb3_model(n_bits, seed, budget)
    eval_seed = seed + EVAL_SEED_OFFSET  # the episodes taskrl evaluates on for this seed
    eval_env = BitFlip(n_bits, num_envs=100, seed=eval_seed)
    return sb3_learn_until(
        model, lambda m: evaluate(sb3_policy(m), eval_env, eval_seed)["success_rate"], eval_interval, target, budget
    )


def updates_per_second(batch_size: int, hidden: tuple[int, ...], n_bits: int = 15, n_updates: int = 600) -> dict:
    """Gradient updates/s (sampling + relabelling + update) at equal batch size and network."""
    # SB3: fill its HER buffer, then time its own train() loop.
    model = sb3_model(n_bits, 0, 10_000, batch_size=batch_size, net_arch=hidden)
    model.learn(total_timesteps=3_000)
    model.train(gradient_steps=50, batch_size=batch_size)
    start = time.perf_counter()
    model.train(gradient_steps=n_updates, batch_size=batch_size)
    sb3 = n_updates / (time.perf_counter() - start)

    # taskrl: the loop's sample -> relabel -> update path, same batch and hidden sizes.
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.replay import EpisodeReplay
    from taskrl.wiring.parts import make_agent, make_env, make_relabeler

    cfg = with_overrides(
        preset_config("bitflip-her"), {"n_bits": n_bits, "batch_size": batch_size, "hidden_sizes": tuple(hidden)}
    )
    env = make_env(cfg, "cpu", num_envs=16, seed=0)
    agent, relabel = make_agent(cfg, env, torch.device("cpu")), make_relabeler(cfg, env)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space, 100_000, num_envs=16, horizon=env.horizon)
    obs = env.reset(seed=0)
    replay.start(obs)
    for _ in range(3_000 // 16):
        action = torch.randint(0, n_bits, (16,))
        nxt, r, te, tr, info = env.step(action)
        replay.add(action, r, te, tr, info["final_obs"], nxt)
    g = torch.Generator().manual_seed(0)

    def one():
        agent.update(relabel(replay.sample(batch_size, g), replay, g))

    for _ in range(50):
        one()
    start = time.perf_counter()
    for _ in range(n_updates):
        one()
    ours = n_updates / (time.perf_counter() - start)
    return {
        "batch_size": batch_size,
        "hidden": list(hidden),
        "sb3_updates_per_s": sb3,
        "taskrl_updates_per_s": ours,
        "ratio": ours / sb3,
    }


def collection_steps_per_second(n_bits: int = 15, steps: int = 30_000) -> dict:
    """Acting + environment stepping + storing, no learning, with each library's own collector."""
    model = sb3_model(n_bits, 0, 10**9)
    model.learning_starts = 10**9  # never train: SB3's collection loop alone
    model.learn(total_timesteps=1_000)
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    sb3 = steps / (time.perf_counter() - start)

    out = {"n_bits": n_bits, "sb3_env_steps_per_s": sb3}
    for num_envs in (16, 256):
        with tempfile.TemporaryDirectory() as tmp:
            run = taskrl.train(
                "bitflip-her",
                out=Path(tmp) / "run",
                n_bits=n_bits,
                num_envs=num_envs,
                total_steps=steps * 4,
                learning_starts=10**12,
                eval_interval=10**12,
                tensorboard=False,
                checkpoint_interval=10**12,
                save_replay=False,
            )
        out[f"taskrl_env_steps_per_s_{num_envs}_envs"] = run.metrics["env_steps"] / run.metrics["wall_seconds"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n-bits", type=int, nargs="+", default=[15, 20, 25])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--libs", nargs="+", default=["taskrl", "sb3"], choices=["taskrl", "sb3"])
    parser.add_argument(
        "--budget", type=int, nargs="+", default=None, help="env-step cap per n (default 150k for n<=15, else 400k)"
    )
    parser.add_argument("--eval-interval", type=int, default=1_000)
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--threads", type=int, default=1, help="torch threads for both libraries")
    parser.add_argument("--skip-throughput", action="store_true")
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/out/her_bitflip.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    budgets = args.budget or [150_000 if n <= 15 else 400_000 for n in args.n_bits]

    runners = {"taskrl": taskrl_time_to_success, "sb3": sb3_time_to_success}
    results: dict = {"runs": [], "throughput": []}
    for n, budget in zip(args.n_bits, budgets):
        for lib in args.libs:
            for seed in args.seeds:
                r = runners[lib](n, seed, budget, args.eval_interval, args.target)
                r.update(lib=lib, n_bits=n, seed=seed, budget=budget)
                results["runs"].append(r)
                print(json.dumps(r), flush=True)
    if not args.skip_throughput:
        for batch, hidden in ((32, (64, 64)), (256, (256, 256))):
            t = updates_per_second(batch, hidden)
            results["throughput"].append(t)
            print(json.dumps(t), flush=True)
        results["collection"] = collection_steps_per_second()
        print(json.dumps(results["collection"]), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=2))

    for r in results["runs"]:
        r["key"] = r["n_bits"]
    table, _ = median_table(results["runs"], args.n_bits, args.libs, "n bits")
    lines = [table]
    if results["throughput"]:
        lines += [
            "",
            "Gradient updates/s (sampling + relabelling + one update), equal batch size and network:",
            "",
            "| batch | hidden | SB3 updates/s | taskrl updates/s | ratio |",
            "|---|---|---|---|---|",
        ]
        for t in results["throughput"]:
            lines.append(
                f"| {t['batch_size']} | {t['hidden']} | {t['sb3_updates_per_s']:,.0f} | {t['taskrl_updates_per_s']:,.0f} | {t['ratio']:.1f}x |"
            )
        c = results["collection"]
        lines += [
            "",
            "Collection only (act + env step + store, no learning), n = 15:",
            "",
            "| SB3 (2 envs, DummyVecEnv) | taskrl (16 envs) | taskrl (256 envs) | ratio (16 envs) | ratio (256 envs) |",
            "|---|---|---|---|---|",
            f"| {c['sb3_env_steps_per_s']:,.0f} | {c['taskrl_env_steps_per_s_16_envs']:,.0f} | {c['taskrl_env_steps_per_s_256_envs']:,.0f} | "
            f"{c['taskrl_env_steps_per_s_16_envs'] / c['sb3_env_steps_per_s']:.0f}x | {c['taskrl_env_steps_per_s_256_envs'] / c['sb3_env_steps_per_s']:.0f}x |",
        ]
    table = "\n".join(lines)
    print(table)
    if args.write:
        append_results(
            "DQN + hindsight relabelling vs Stable-Baselines3 (random-goal bit flipping)",
            f"Seeds {args.seeds}, eval every {args.eval_interval} env steps on 100 fixed episodes, "
            f"torch threads = {args.threads} for both, evaluation excluded from both clocks.\n\n{table}",
        )


if __name__ == "__main__":
    main()
