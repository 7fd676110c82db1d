"""Learner speed: taskrl against Stable-Baselines3 at equal work, and against the FLOP bound.

``equal``: both libraries with the same settings, in one script, on the same machine and thread count:

- DQN + HER on random-goal bit flipping (n = 15), at SB3's settings of its HER test: 2 envs, one
  gradient update per env step (``gradient_steps = n_envs`` every step), lr 2e-3, gamma 0.99, Huber loss,
  gradient-norm clip 10, no double-Q, a hard target copy every 100 updates, epsilon 1.0 -> 0.05 over the
  first 20k env steps, 100 learning-starts steps, a 100k replay, HER ``future`` with k = 4; at batch 32 /
  (64, 64) and batch 256 / (256, 256).
- SAC + HER on FetchReach-v4, at rl-baselines3-zoo's settings: 1 env, one update per env step, gamma
  0.95, lr 1e-3, batch 256, (64, 64), tau 0.005, temperature learned from 1.0, 1000 learning-starts
  steps, a 1M replay, HER ``future`` with k = 4, observation normalisation.

For each, over seeds: wall-clock and env steps to 90% success (evaluation on the same 100 episodes every
1000 env steps, by the same function, excluded from both clocks), then training throughput over a fixed
budget with no evaluation: env steps/s and gradient updates/s. taskrl runs eager, ``--compile default``,
and compiled with 4 updates per call (``--updates-per-call 4``: the same updates, made in groups of 4).

``bound``: ms per gradient update on a fixed batch (sampling apart) against the FLOP bound: the update's
floating-point operations (counted by ``torch.utils.flop_counter`` on one eager update: matrix products,
forward and backward) over the best matrix-multiply rate measured on this machine. DQN and SAC at
(256, 256) / batch 256, and multi-task SAC at the MT10 presets' scale ((400, 400, 400), batch 1280),
eager and compiled, with the compile step's own cost and the run length from which it pays.

    .venv/bin/python benchmarks/learner_speed.py bound --write
    .venv/bin/python benchmarks/learner_speed.py equal --seeds 0 1 2 --write
    .venv/bin/python benchmarks/learner_speed.py curves --seeds 0 1 2 --write
    .venv/bin/python benchmarks/learner_speed.py loop --write
    .venv/bin/python benchmarks/learner_speed.py kernels --write

``loop``: each piece of the off-policy loop (update, sample + relabel, act, env step, store) timed inside a real
DQN + HER run at the equal-work settings, eager and compiled, at both network sizes.

``kernels``: where the time of the compiled DQN (256, 256) / 256 update goes (matrix products, the Adam step,
the other generated kernels, the wrapper and guards), from Inductor's kernel profile, against its bound.

``curves``: each compiling algorithm's small preset trained eagerly and with ``--compile default`` on the
same seeds: the evaluation curves (mean over seeds, in ``figures/learner_curves.png``) and final success.
A compiled run draws its random numbers from the compiler's generator, so runs are compared as
distributions over seeds, not row by row (eager runs are compared row by row with a base commit by
``same_learning.py``).
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

import taskrl
from common import alternating_blocks, append_results, fresh_compile_cache, sb3_learn_until, taskrl_learn_until
from taskrl.replay.batch import Batch
from taskrl.training.evaluation import evaluate
from taskrl.wiring.parts import EVAL_SEED_OFFSET

RESULTS_DIR = Path(__file__).with_name("results")

# ----------------------------------------------------------------------------- equal work
#: taskrl settings equal to SB3's DQN + HER bit-flipping settings (``her_bitflip.sb3_model``)
DQN_EQUAL = dict(
    n_bits=15,
    num_envs=2,
    updates_per_step=1.0,
    lr=2e-3,
    gamma=0.99,
    loss="huber",
    max_grad_norm=10.0,
    double_q=False,
    target_update_interval=100,
    tau=1.0,
    clip_target=False,
    normalize_inputs=False,
    epsilon_start=1.0,
    epsilon_end=0.05,
    epsilon_decay_steps=20_000,
    learning_starts=100,
    buffer_size=100_000,
    her="future",
    her_k=4,
)
#: taskrl settings equal to rl-baselines3-zoo's SAC + HER FetchReach settings (``her_fetch.sb3_time_to_success``)
SAC_EQUAL = dict(
    num_envs=1,
    updates_per_step=1.0,
    gamma=0.95,
    lr=1e-3,
    batch_size=256,
    hidden_sizes=(64, 64),
    tau=0.005,
    init_alpha=1.0,
    learning_starts=1000,
    buffer_size=1_000_000,
    her="future",
    her_k=4,
    normalize_inputs=True,
)
DIFFERENCES = {
    "dqn": "SB3's network reads observation, achieved and desired goal (45 inputs), taskrl's observation and "
    "desired goal (30); SB3 computes a relabelled transition's termination as stored, taskrl for the new goal; "
    "SB3 copies the target every 100 env steps (50 calls of 2), taskrl every 100 updates (the same count at one "
    "update per env step); SB3's throughput runs step SB3's own `BitFlippingEnv` (numpy, one copy per env, its goal "
    "fixed at all ones), as a user's SB3 script would, and its time-to-90% runs taskrl's random-goal env so that both "
    "learn the same task; taskrl steps its native batched torch env in both",
    "sac": "SB3 (the zoo's `normalize: True`) also normalises rewards with VecNormalize, taskrl normalises observations "
    "only (running mean/std from training batches, clipped to +-5, against VecNormalize's clip 10)",
}


def _taskrl_run(
    preset: str, settings: dict, seed: int, budget: int, eval_interval: int, target: float, compile_mode: str
) -> dict:
    r = taskrl_learn_until(preset, seed, budget, eval_interval, target, compile=compile_mode, **settings)
    return {**r, "updates_per_s_after_compile": r["updates"] / max(r["seconds"] - r["compile_seconds"], 1e-9)}


def dqn_case(batch: int, hidden: tuple[int, ...]):
    from her_bitflip import sb3_model, sb3_policy
    from taskrl.envs import BitFlip

    settings = {**DQN_EQUAL, "batch_size": batch, "hidden_sizes": hidden}
    n = DQN_EQUAL["n_bits"]

    def sb3(seed: int, budget: int, eval_interval: int, target: float) -> dict:
        # throughput: SB3 at its own full speed, on its own env as a user's script would run it
        model = sb3_model(n, seed, budget, batch_size=batch, net_arch=hidden, own_env=target <= 0)
        if target <= 0:
            return _sb3_throughput(model, budget)
        eval_seed = seed + EVAL_SEED_OFFSET
        eval_env = BitFlip(n, num_envs=100, seed=eval_seed)
        r = sb3_learn_until(
            model, lambda m: evaluate(sb3_policy(m), eval_env, eval_seed)["success_rate"], eval_interval, target, budget
        )
        return {**r, "updates": model._n_updates}

    def ours(seed, budget, eval_interval, target, compile_mode, per_call):
        return _taskrl_run(
            "bitflip-her", {**settings, "updates_per_call": per_call}, seed, budget, eval_interval, target, compile_mode
        )

    return f"dqn-her bitflip n=15, batch {batch}, {list(hidden)}", sb3, ours


def sac_case():
    from her_fetch import sb3_model, sb3_time_to_success

    def sb3(seed: int, budget: int, eval_interval: int, target: float) -> dict:
        if target <= 0:
            return _sb3_throughput(sb3_model(seed)[0], budget)
        return sb3_time_to_success(seed, budget, eval_interval, target, normalize=True)

    def ours(seed, budget, eval_interval, target, compile_mode, per_call):
        return _taskrl_run(
            "fetchreach-sac-her", {**SAC_EQUAL, "updates_per_call": per_call}, seed, budget, eval_interval, target, compile_mode
        )

    return "sac-her FetchReach-v4, batch 256, [64, 64]", sb3, ours


def _sb3_throughput(model, budget: int) -> dict:
    start = time.perf_counter()
    model.learn(total_timesteps=budget)
    seconds = time.perf_counter() - start
    return {
        "env_steps": model.num_timesteps,
        "updates": model._n_updates,
        "seconds": seconds,
        "env_steps_per_s": model.num_timesteps / seconds,
        "updates_per_s": model._n_updates / seconds,
    }


def _median(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def _earlier_runs(log: Path | None, seeds: list[int]) -> dict:
    """``(case, lib, kind, seed) -> result`` from an earlier run's log of JSON lines (seeds in order
    where a line has none), for ``--reuse-log``."""
    found, count = {}, {}
    for line in log.read_text().splitlines() if log else []:
        if not line.startswith('{"case"'):
            continue
        r = json.loads(line)
        kind = "to_target" if "to_target" in r else "throughput"
        at = (r["case"], r["lib"], kind)
        seed = r.get("seed", seeds[count.get(at, 0)] if count.get(at, 0) < len(seeds) else None)
        count[at] = count.get(at, 0) + 1
        found[(*at, seed)] = r[kind]
    return found


def _with_compile(ours, compile_mode: str, per_call: int, *args):
    return ours(*args, compile_mode, per_call)


#: what a no-flag arm's process finds in its compile cache: nothing (the machine's first compile), another
#: network's graphs (a first run of these shapes on a machine that compiled before), or these shapes' graphs (a later run)
CACHE_BEFORE = {"taskrl, no flag, first compile on the machine": "nothing", "taskrl, no flag": "other shapes",
                "taskrl, no flag, later run": "same shapes"}  # fmt: skip


def _no_flag_run(key: str, before: str, seed: int, budget: int, interval: int, target: float) -> dict:
    """A user's run with no flag, in a new process with a compile cache of this arm's own (so no other arm warms it
    and no in-memory cache of this process helps), holding ``before`` (`CACHE_BEFORE`): for "other shapes" an earlier
    process (not timed) compiled the other DQN case's update, for "same shapes" it ran this very training."""
    import os
    import shutil
    import subprocess
    import sys

    cache = tempfile.mkdtemp(prefix="taskrl-inductor-arm-")
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache}

    def one_run(case: str, steps: int, compile_mode: str) -> dict:
        command = [sys.executable, str(Path(__file__).resolve()), "one", "--cases", case, "--seeds", str(seed)]
        command += ["--throughput-steps", str(steps), "--one-compile", compile_mode]
        done = subprocess.run(command, env=env, check=True, capture_output=True, text=True)
        return json.loads(done.stdout.strip().splitlines()[-1])

    try:
        if before == "other shapes":
            one_run("dqn256" if key == "dqn32" else "dqn32", 300, "default")
        elif before == "same shapes":
            one_run(key, budget, "auto")
        return one_run(key, budget, "auto")
    finally:
        shutil.rmtree(cache, ignore_errors=True)


#: the equal-work cases by name: ``() -> (title, sb3 runner, taskrl runner)``
EQUAL_CASES = {"dqn32": lambda: dqn_case(32, (64, 64)), "dqn256": lambda: dqn_case(256, (256, 256)), "sac": lambda: sac_case()}


def one(args) -> None:
    """Print the result of one taskrl throughput run (``--cases KEY --seeds S --throughput-steps N``, compiled as
    ``--one-compile``, updates per call auto), for `_no_flag_run`'s processes."""
    _, _, ours = EQUAL_CASES[args.cases[0]]()
    result = _with_compile(ours, args.one_compile, 0, args.seeds[0], args.throughput_steps, 10**12, 0.0)
    print(json.dumps(result), flush=True)


#: env steps of SB3's run that sizes ``--slice-seconds``
SB3_PROBE_STEPS = 5_000


def equal(args) -> tuple[str, dict]:
    budgets = {"dqn32": (100_000, 20_000), "dqn256": (100_000, 20_000), "sac": (20_000, 6_000)}
    if args.throughput_steps:
        budgets = {key: (to_target, args.throughput_steps) for key, (to_target, _) in budgets.items()}
    out, lines = {}, []
    reused = _earlier_runs(args.reuse_log, args.seeds)
    for key in args.cases:
        title, sb3, ours = EQUAL_CASES[key]()
        to_target, throughput_steps = budgets[key]
        earlier_sb3 = reused.get((key, "sb3", "throughput", args.seeds[0])) if "sb3" in args.reuse_libs else None
        if args.slice_seconds and earlier_sb3:  # the slice the reused runs were measured on
            throughput_steps = earlier_sb3["env_steps"]
        elif args.slice_seconds:  # equal work that SB3 does in about that long, at its rate measured here and now
            probe = sb3(args.seeds[0], SB3_PROBE_STEPS, 10**12, 0.0)
            throughput_steps = int(args.slice_seconds * probe["updates"] / probe["seconds"])
            print(f"{key}: SB3 made {probe['updates'] / probe['seconds']:.0f} updates/s over {SB3_PROBE_STEPS:,} env steps: "
                  f"{args.slice_seconds:.0f} s slices are {throughput_steps:,} env steps", flush=True)  # fmt: skip
        runners = {
            "sb3": sb3,
            "taskrl": functools.partial(_with_compile, ours, "off", 1),
            "taskrl compiled": functools.partial(_with_compile, ours, "default", 1),
            "taskrl compiled, 4 per call": functools.partial(_with_compile, ours, "default", 4),
            # what a user gets with no flag (--compile auto --updates-per-call auto chose from the budget), each
            # in a new process whose compile cache holds what `CACHE_BEFORE` says
            **{lib: functools.partial(_no_flag_run, key, before) for lib, before in CACHE_BEFORE.items()},
        }
        runners = {lib: run for lib, run in runners.items() if not args.libs or lib in args.libs or lib == "sb3"}
        runs: dict[str, dict[str, list]] = {lib: {"target": [], "throughput": []} for lib in runners}
        # seed by seed, every library in turn: the machine's drift over the minutes of a case falls on all alike
        for seed in args.seeds:
            for lib, runner in runners.items():
                kinds = {"to_target": (to_target, 1_000, args.target), "throughput": (throughput_steps, 10**12, 0.0)}
                if args.throughput_only:
                    kinds.pop("to_target")
                for kind, (budget, interval, target) in kinds.items():
                    keep = lib in args.reuse_libs or f"{key}/{lib}" in args.reuse_libs
                    r = reused.get((key, lib, kind, seed)) if keep else None
                    if r is None:
                        r = runner(seed, budget, interval, target)
                        print(json.dumps({"case": key, "lib": lib, kind: r, "seed": seed}), flush=True)
                    runs[lib]["target" if kind == "to_target" else "throughput"].append({**r, "seed": seed})
        out[key] = {"title": title, "runs": runs}
        lines += [f"**{title}** ({len(args.seeds)} seeds; medians)", ""]
        lines += [
            "| library | solved | env steps to 90% | seconds to 90% | training env steps/s | training updates/s | "
            "updates/s after compiling | ratio of updates/s to SB3 |",
            "|---|---|---|---|---|---|---|---|",
        ]
        sb3_rate = _median(runs["sb3"]["throughput"], "updates_per_s")
        for lib, r in runs.items():
            t, p = r["target"], r["throughput"]
            after = (
                _median(p, "updates_per_s_after_compile")
                if "updates_per_s_after_compile" in p[0]
                else _median(p, "updates_per_s")
            )
            reached = (
                f"{sum(x['solved'] for x in t)}/{len(t)} | {_median(t, 'env_steps'):,.0f} | {_median(t, 'seconds'):.1f}"
                if t
                else "not run | | "
            )
            lines.append(
                f"| {lib} | {reached} | "
                f"{_median(p, 'env_steps_per_s'):,.0f} | {_median(p, 'updates_per_s'):,.0f} | {after:,.0f} | "
                f"{_median(p, 'updates_per_s') / sb3_rate:.2f}x ({after / sb3_rate:.2f}x after compiling) |"
            )
        no_flag = [lib for lib in CACHE_BEFORE if lib in runs and runs[lib]["throughput"]]
        if no_flag:
            chosen = sorted({r.get("path", "?") for lib in no_flag for r in runs[lib]["throughput"]})
            seconds = {lib: _median(r["throughput"], "seconds") for lib, r in runs.items() if r["throughput"]}
            lines.append(
                f"\nWith no flag the runs chose: {'; '.join(chosen)}. Seconds for the same work (compile included): "
                + ", ".join(f"{lib} {s:.1f}" for lib, s in seconds.items())
                + "; SB3 / "
                + ", SB3 / ".join(f"{lib.removeprefix('taskrl, ')}: {seconds['sb3'] / seconds[lib]:.2f}x" for lib in no_flag)
                + (
                    f"; eager / no flag: {seconds['taskrl'] / seconds['taskrl, no flag']:.2f}x"
                    if {"taskrl", "taskrl, no flag"} <= set(seconds)
                    else ""
                )
            )
        if runs["sb3"]["target"]:
            sb3_seconds = _median(runs["sb3"]["target"], "seconds")
            for lib in list(runners)[1:]:
                lines.append(f"\nWall-clock to 90%, SB3 / {lib}: {sb3_seconds / _median(runs[lib]['target'], 'seconds'):.2f}x")
        differences = DIFFERENCES["sac" if key == "sac" else "dqn"]
        said = differences in "\n".join(lines)  # one case per section says it; the next ones point back
        lines += ["", "Differences left: as for the case above." if said else f"Differences left: {differences}.", ""]
        lines.append(
            f"Per-seed throughput runs: {throughput_steps:,} env steps each, no evaluation; time-to-90% runs: up to {to_target:,}."
        )
        lines.append("")
    return "\n".join(lines), out


# ----------------------------------------------------------------------------- the bound
def matmul_rate() -> float:
    """The best float32 matrix-multiply rate (FLOP/s) over square sizes, on this thread count."""
    best = 0.0
    for n in (256, 512, 1024):
        a, b = torch.randn(n, n), torch.randn(n, n)
        for _ in range(5):
            a @ b
        reps = max(3, int(2e9 / (2 * n**3)))
        start = time.perf_counter()
        for _ in range(reps):
            a @ b
        best = max(best, 2 * n**3 * reps / (time.perf_counter() - start))
    return best


def with_plain_layers(agent):
    """``agent`` with each ``nets.Linear`` made a plain ``nn.Linear`` (the same parameters; no layouts)."""
    from torch import nn

    for part in agent._parts().values():
        for module in part.modules() if isinstance(part, nn.Module) else ():
            if isinstance(module, nn.Linear):
                module.__class__ = nn.Linear
    return agent


def update_flops(agent, batch) -> int:
    from torch.utils.flop_counter import FlopCounterMode

    twin = with_plain_layers(copy.deepcopy(agent))  # the algorithm's work: without the zero rows of a padded head
    with FlopCounterMode(display=False) as counter:
        twin.update(batch)
    return counter.get_total_flops()


def schedule_period(agent) -> int:
    """Updates after which every variant of the step has run (a target refresh every N updates is a second graph)."""
    cfg = agent.config
    return max(getattr(cfg, "target_update_interval", 1), getattr(cfg, "policy_delay", 1), getattr(cfg, "target2_interval", 1))


def bitflip_replay(settings: dict, steps: int = 4_000):
    """``(config, env, replay)``: the bit-flipping preset with ``settings``, 16 envs, and a replay of ``steps``
    random-action env steps."""
    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.replay import EpisodeReplay
    from taskrl.run import make_env

    cfg = with_overrides(preset_config("bitflip-her"), settings)
    env = make_env(cfg, "cpu", num_envs=16, seed=0)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space, 100_000, num_envs=16, horizon=env.horizon)
    replay.start(env.reset(seed=0))
    for _ in range(steps // 16):
        action = torch.randint(0, cfg.env_settings.n_bits, (16,))
        nxt, r, te, tr, info = env.step(action)
        replay.add(action, r, te, tr, info["final_obs"], nxt)
    return cfg, env, replay


def bitflip_agent_and_batch(batch_size: int, hidden: tuple[int, ...], double_q: bool):
    """A DQN agent at the equal-work settings (or with double-Q) and one relabelled batch from a filled replay,
    with the cost of sampling + relabelling that batch."""
    from taskrl.wiring.parts import make_agent, make_relabeler

    settings = {**DQN_EQUAL, "batch_size": batch_size, "hidden_sizes": hidden, "double_q": double_q}
    cfg, env, replay = bitflip_replay(settings)
    agent, relabel = make_agent(cfg, env, torch.device("cpu")), make_relabeler(cfg, env)
    g = torch.Generator().manual_seed(0)
    for _ in range(20):
        relabel(replay.sample(batch_size, g), replay, g)
    start, n = time.perf_counter(), 2_000
    for _ in range(n):
        relabel(replay.sample(batch_size, g), replay, g)
    sample_ms = (time.perf_counter() - start) / n * 1e3
    return agent, relabel(replay.sample(batch_size, g), replay, g), sample_ms


def sac_agent_and_batch(batch_size: int, hidden: tuple[int, ...], in_dim: int, action_dim: int, tasks: int = 0, preset: str = ""):
    """A SAC agent and a random batch of its shapes (FetchReach's 13 inputs and 4 actions; or an MT10 preset's)."""
    from taskrl.agents.sac import SACAgent, SACConfig

    conditioning = None
    if tasks:
        from taskrl.conditioning.networks import make_conditioning
        from taskrl.overrides import with_overrides
        from taskrl.presets import preset_config

        cfg = with_overrides(preset_config(preset), {})
        descriptions = [f"task {i}" for i in range(tasks)]
        conditioning = make_conditioning(cfg.conditioning, tasks, descriptions)
        config = cfg.algo_settings
    else:
        config = SACConfig(hidden_sizes=hidden)
    low, high = -torch.ones(action_dim), torch.ones(action_dim)
    agent = SACAgent(("observation",), in_dim, (low, high), config, conditioning=conditioning)
    g = torch.Generator().manual_seed(0)
    obs = {"observation": torch.randn(batch_size, in_dim, generator=g)}
    nxt = {"observation": torch.randn(batch_size, in_dim, generator=g)}
    if tasks:
        obs["task"] = nxt["task"] = torch.arange(batch_size) % tasks
    batch = Batch(
        obs=obs,
        action=torch.rand(batch_size, action_dim, generator=g) * 2 - 1,
        reward=-torch.rand(batch_size, generator=g),
        next_obs=nxt,
        terminated=torch.zeros(batch_size, dtype=torch.bool),
        truncated=torch.zeros(batch_size, dtype=torch.bool),
        episode=torch.zeros(batch_size, dtype=torch.long),
        step=torch.zeros(batch_size, dtype=torch.long),
    )
    return agent, batch, 0.0


def mt10_agent_and_batch(preset: str):
    """An MT10 preset's SAC agent (batch 1280, 39 inputs, 4 actions, 10 tasks) and a random batch of its shapes."""
    return sac_agent_and_batch(1280, (), 39, 4, 10, preset)


def bound(args) -> tuple[str, dict]:
    # The machine's speed drifts by 20-30% over minutes: the paths of a case are timed side by side, each
    # block against the matrix-multiply rate of its own round.
    rate = matmul_rate()
    cases = {
        "DQN (64, 64) / 32, as SB3's": lambda: bitflip_agent_and_batch(32, (64, 64), False),
        "DQN (256, 256) / 256, as SB3's": lambda: bitflip_agent_and_batch(256, (256, 256), False),
        "DQN (256, 256) / 256, double-Q": lambda: bitflip_agent_and_batch(256, (256, 256), True),
        "SAC (256, 256) / 256, FetchReach shapes": lambda: sac_agent_and_batch(256, (256, 256), 13, 4),
        "SAC (64, 64) / 256, FetchReach shapes": lambda: sac_agent_and_batch(256, (64, 64), 13, 4),
        "MT10 SAC one-hot (400, 400, 400) / 1280": lambda: mt10_agent_and_batch("mt10-sac-onehot"),
        "MT10 SAC CARE (400, 400, 400) / 1280": lambda: mt10_agent_and_batch("mt10-sac-care"),
    }
    rows, out = [], {"matmul_gflops": rate / 1e9, "cases": []}
    # the machine's one-time compile pieces (the C++ compiler's checks, torch's precompiled header: about 4 s) are
    # built first by a throwaway update, so that each case's compile seconds are those of its own shapes
    tiny, tiny_batch, _ = bitflip_agent_and_batch(8, (8,), False)
    tiny.compile("default", say=lambda line: None)
    tiny.update(tiny_batch)
    for name, make in cases.items():
        if args.only and not any(word in name for word in args.only):
            continue
        agent, batch, sample_ms = make()
        flops = update_flops(agent, batch)
        compiled = copy.deepcopy(agent)
        compiled.compile("default", say=lambda line: None)
        warm, start = schedule_period(agent) + 1, time.perf_counter()
        for _ in range(warm):  # the first call compiles, and the first target refresh compiles its variant
            compiled.update(batch)
        warm_seconds = time.perf_counter() - start
        many = copy.deepcopy(agent)
        many.compile("default", say=lambda line: None)
        together = Batch.interleave([batch] * args.per_call)  # K batches in one, split inside the step
        many_calls, start = -(-(schedule_period(agent) + 1) // args.per_call), time.perf_counter()
        for _ in range(many_calls):
            many.update_many(together, args.per_call)
        many_warm_seconds = time.perf_counter() - start
        for _ in range(schedule_period(agent) + 5):
            agent.update(batch)
        paths = {  # path: (call, its argument, updates per call)
            "eager": (agent.update, batch, 1),
            "compiled": (compiled.update, batch, 1),
            "many": (functools.partial(many.update_many, k=args.per_call), together, args.per_call),
        }

        # side by side: round by round, the matrix-multiply rate and then a block of each path (in turn
        # first), so each path's ratio to the bound is taken against the rate of its own minutes
        def block(call, argument, count) -> int:
            n, start = 0, time.perf_counter()
            while time.perf_counter() - start < args.seconds / args.rounds:
                call(argument)
                n += count
            return n

        rates = []
        ms = alternating_blocks(
            {path: functools.partial(block, *spec) for path, spec in paths.items()},
            args.rounds,
            before_round=lambda rates=rates: rates.append(matmul_rate()),
        )
        x_bound = {path: [t / (flops / rate * 1e3) for t, rate in zip(times, rates)] for path, times in ms.items()}
        eager_ms, compiled_ms, many_ms = (statistics.median(ms[path]) for path in paths)
        eager_x, compiled_x, many_x = (statistics.median(x_bound[path]) for path in paths)
        if not compiled.step.active:
            compiled_ms = compiled_x = float("nan")
        if not many.step_many.active:
            many_ms = many_x = float("nan")
        compile_s = warm_seconds - warm * compiled_ms / 1e3 if compiled.step.active else float("nan")
        many_compile_s = many_warm_seconds - many_calls * args.per_call * many_ms / 1e3 if many.step_many.active else float("nan")
        pays_after = compile_s / max((eager_ms - compiled_ms) / 1e3, 1e-12) if eager_ms > compiled_ms else float("inf")
        case_rate = statistics.median(rates)
        bound_ms = flops / case_rate * 1e3
        r = dict(
            case=name,
            matmul_gflops=case_rate / 1e9,
            mflop=flops / 1e6,
            bound_ms=bound_ms,
            eager_ms=eager_ms,
            compiled_ms=compiled_ms,
            compiled_many_ms=many_ms,
            x_bound={"eager": eager_x, "compiled": compiled_x, "many": many_x},
            per_round_ms=ms,
            per_round_gflops=[r / 1e9 for r in rates],
            per_call=args.per_call,
            sample_relabel_ms=sample_ms,
            compile_seconds=compile_s,
            compile_many_seconds=many_compile_s,
            pays_after_updates=pays_after,
        )
        out["cases"].append(r)
        print(json.dumps(r), flush=True)
        rows.append(
            f"| {name} | {flops / 1e6:,.0f} | {case_rate / 1e9:.1f} | {bound_ms:.2f} | {eager_ms:.2f} ({eager_x:.2f}x) | "
            f"{compiled_ms:.2f} ({compiled_x:.2f}x) | {many_ms:.2f} ({many_x:.2f}x) | {eager_ms / compiled_ms:.2f}x | "
            f"{sample_ms:.2f} | {compile_s:.1f} | {many_compile_s:.1f} | {pays_after:,.0f} |"
        )
    table = "\n".join(
        [
            f"Matrix-multiply rate (best of 256, 512, 1024 square float32 products, one thread): {rate / 1e9:.1f} GFLOP/s "
            f"at the start. Each case runs its three paths side by side: {args.rounds} rounds, each the matrix-multiply "
            f"rate, then a block of each path ({args.seconds / args.rounds:.2f} s, the first path rotating). ms: the median "
            "over rounds; x bound: the median over rounds of each block's ms against the bound at its round's rate; "
            "GFLOP/s and bound ms: the median rate. MFLOP: the matrix products of one update, without the zero rows "
            "of `nets.Linear`'s padded heads.",
            "",
            "| update | MFLOP | GFLOP/s | bound ms | eager ms (x bound) | compiled ms (x bound) | "
            f"compiled, {args.per_call} per call, ms per update (x bound) | compiled speed-up | "
            f"sample + relabel ms | compile s | compile s, {args.per_call} per call | compile pays after (updates) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return table, out


# ----------------------------------------------------------------------------- learning, eager against compiled
#: case -> (preset, overrides): one per algorithm whose update compiles (multi-task SAC included)
CURVE_CASES = {
    "dqn": ("bitflip-her", dict(n_bits=8, total_steps=6_000, eval_interval=1_000)),
    "sac": ("pointreach-sac-her", dict(total_steps=20_000, eval_interval=4_000)),
    "td3": ("pointreach-sac-her", dict(algo="td3", total_steps=20_000, eval_interval=4_000)),
    # QT-Opt has barely started at 4k env steps (0.09 and 0.11 success); at 12k its learning test reaches 0.9
    "qtopt": ("pointreach-qtopt-her", dict(total_steps=12_000, eval_interval=3_000)),
    "mt-sac": ("pointreach-mt-sac-onehot", dict(total_steps=16_000, eval_interval=4_000)),
}


def _curve(preset: str, overrides: dict, seed: int, compile_mode: str) -> dict:
    import csv

    with tempfile.TemporaryDirectory() as tmp:
        run = taskrl.train(preset, out=Path(tmp) / "run", seed=seed, compile=compile_mode, tensorboard=False, **overrides)
        rows = [r for r in csv.DictReader(open(Path(tmp) / "run" / "metrics.csv")) if r.get("success_rate")]
    return {
        "env_steps": [int(float(r["env_steps"])) for r in rows],
        "success": [float(r["success_rate"]) for r in rows],
        "seconds": run.metrics["wall_seconds"],
    }


def curves(args) -> tuple[str, dict]:
    """Evaluation curves of each algorithm's small preset, eager and compiled, over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out, lines = (
        {},
        ["| case | preset | seeds | final success, eager | final success, compiled | mean abs. difference of the mean curves |"],
    )
    lines.append("|---|---|---|---|---|---|")
    fig, axes = plt.subplots(1, len(args.curve_cases), figsize=(3.2 * len(args.curve_cases), 3), squeeze=False)
    for ax, case in zip(axes[0], args.curve_cases):
        preset, overrides = CURVE_CASES[case]
        runs = {mode: [_curve(preset, overrides, seed, mode) for seed in args.seeds] for mode in ("off", "default")}
        out[case] = runs
        means = {}
        for mode, label in (("off", "eager"), ("default", "compiled")):
            steps = runs[mode][0]["env_steps"]
            means[mode] = [statistics.mean(r["success"][i] for r in runs[mode]) for i in range(len(steps))]
            ax.plot(steps, means[mode], label=label)
        ax.set_title(case)
        ax.set_xlabel("env steps")
        ax.set_ylim(0, 1.02)
        gap = statistics.mean(abs(a - b) for a, b in zip(means["off"], means["default"]))
        final = {m: [r["success"][-1] for r in runs[m]] for m in runs}
        lines.append(
            f"| {case} | {preset} {overrides} | {len(args.seeds)} | "
            f"{statistics.mean(final['off']):.2f} ({', '.join(f'{x:.2f}' for x in final['off'])}) | "
            f"{statistics.mean(final['default']):.2f} ({', '.join(f'{x:.2f}' for x in final['default'])}) | {gap:.3f} |"
        )
        print(lines[-1], flush=True)
    axes[0][0].set_ylabel("success (mean over seeds)")
    axes[0][0].legend()
    fig.tight_layout()
    # a run of some cases keeps the figure of all of them
    suffix = "" if list(args.curve_cases) == list(CURVE_CASES) else "_" + "_".join(c.replace("-", "") for c in args.curve_cases)
    figure = Path(__file__).with_name("figures") / f"learner_curves{suffix}.png"
    fig.savefig(figure, dpi=110)
    return "\n".join(lines) + f"\n\nCurves: `benchmarks/figures/{figure.name}`.", out


# ----------------------------------------------------------------------------- where a compiled update's time goes
def _kernel_group(name: str) -> str | None:
    """The part of a compiled update a profiler event belongs to (None: counted inside another event)."""
    if name in ("aten::addmm", "aten::mm"):
        return "matrix products"
    if name == "aten::copy_":
        return "bias copies into the products' outputs"
    if name.startswith("graph_") and "_foreach_" in name:
        return "Adam step + clip norms (one generated kernel)"
    if name.startswith("graph_"):
        return "other generated kernels (ReLU and its backward, loss, gathers)"
    if name.startswith("## Call CompiledFxGraph") or name.startswith("Torch-Compiled Region"):
        return "graph wrapper (Python here; C++ in the shipped path)"
    if name in ("TorchDynamo Cache Lookup", "AOTDispatcher Runtime Wrapper Prologue", "Pregraph bytecode"):
        return "guards and call prologue"
    return None


def kernels(args) -> tuple[str, dict]:
    """Where the time of the compiled DQN (256, 256) / 256 update goes: Inductor's kernel profile of the update
    (its generated kernels and the library's matrix products as events of their own), against its FLOP bound.
    The graph's wrapper is generated as Python here (the profile cannot see inside a C++ one); the update as
    shipped (C++ wrapper) is timed beside it."""
    import torch._inductor.config as inductor_config
    from torch.profiler import ProfilerActivity, profile

    import taskrl.agents.compiled as compiled_module

    shipped_options = compiled_module.compile_options
    agent, batch, _ = bitflip_agent_and_batch(256, (256, 256), False)
    flops = update_flops(agent, batch)
    warm = schedule_period(agent) * 2 + 1  # updates that compile every variant of the step
    shipped = copy.deepcopy(agent)
    shipped.compile("default", say=lambda line: None)
    for _ in range(warm):  # compiled as a run compiles it, before the profiled twin's settings
        shipped.update(batch)
    try:  # the profiled twin: Python wrapper, kernels recorded
        compiled_module.compile_options = lambda mode, device="cpu": {**shipped_options(mode, device), "cpp_wrapper": False}
        with inductor_config.patch({"cpp.enable_kernel_profile": True}):
            agent.compile("default", say=lambda line: None)
            for _ in range(warm):
                agent.update(batch)
            n, rounds, parts, rates, ms = 300, 3, {}, [], {"profiled": [], "shipped": []}
            for r in range(rounds):
                rates.append(matmul_rate())
                for key, twin in (("profiled", agent), ("shipped", shipped)):
                    start = time.perf_counter()
                    for _ in range(n):
                        twin.update(batch)
                    ms[key].append((time.perf_counter() - start) / n * 1e3)
                with profile(activities=[ProfilerActivity.CPU]) as prof:
                    for _ in range(n):
                        agent.update(batch)
                for event in prof.key_averages():
                    group = _kernel_group(event.key)
                    if group:
                        parts.setdefault(group, [0.0] * rounds)[r] += event.self_cpu_time_total / n / 1e3
    finally:
        compiled_module.compile_options = shipped_options
    rate = statistics.median(rates)
    bound_ms = flops / rate * 1e3
    median_parts = {g: statistics.median(v) for g, v in parts.items()}  # each round: the sum of the group's self times
    profiled, shipped_ms = statistics.median(ms["profiled"]), statistics.median(ms["shipped"])
    rows = [f"| {g} | {t:.3f} | {t / bound_ms:.2f} |" for g, t in sorted(median_parts.items(), key=lambda kv: -kv[1])]
    accounted = sum(median_parts.values())
    table = "\n".join(
        [
            f"DQN (256, 256) / 256 as SB3's, compiled (default), {flops / 1e6:.0f} MFLOP: the bound is {bound_ms:.2f} ms at "
            f"{rate / 1e9:.1f} GFLOP/s (median of {rounds} rounds of the matrix-multiply rate). One update took "
            f"{shipped_ms:.2f} ms as shipped (C++ wrapper; {shipped_ms / bound_ms:.2f}x the bound) and {profiled:.2f} ms with the "
            f"Python wrapper profiled here ({profiled / bound_ms:.2f}x). ms per update by part, from the profile (self "
            f"times; median of {rounds} rounds of {n} updates). The parts sum to {accounted:.2f} ms against {profiled:.2f} ms "
            "timed without the profiler: the profiler's own cost is in them, most in the small parts.",
            "",
            "| part | ms per update | x bound |",
            "|---|---|---|",
            *rows,
        ]
    )
    data = {
        "mflop": flops / 1e6,
        "matmul_gflops": [r / 1e9 for r in rates],
        "bound_ms": bound_ms,
        "update_ms": ms,
        "parts_ms": parts,
    }
    return table, data


# ----------------------------------------------------------------------------- where a run's time goes
class _Clock:
    """Seconds and calls of wrapped functions, leaving out each one's first ``skip`` calls."""

    def __init__(self, skip: int) -> None:
        self.skip, self.seconds, self.calls = skip, {}, {}

    def wrap(self, name: str, fn):
        def run(*a, **k):
            self.calls[name] = self.calls.get(name, 0) + 1
            start = time.perf_counter()
            result = fn(*a, **k)
            if self.calls[name] > self.skip:
                self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            return result

        return run

    def ms_per_call(self) -> dict[str, float]:
        return {n: self.seconds.get(n, 0.0) / max(c - self.skip, 1) * 1e3 for n, c in self.calls.items()}


def _clocked_sampler(clock: _Clock, sampler, *args, **kwargs):
    return clock.wrap("sample + relabel", sampler(*args, **kwargs))


def loop(args) -> tuple[str, dict]:
    """The parts of one env step of a real run (DQN + HER at the equal-work settings, 2 envs, one update per env step),
    each wrapped with a clock (the first 300 calls of each, compilation and warm-up, left out), against the bound of
    the update's matrix products and SB3's whole step on the same case (its throughput run of as many env steps)."""
    import taskrl.agents.base as base
    import taskrl.agents.dqn as dqn
    import taskrl.envs.bitflip as bitflip
    import taskrl.replay.storage as storage
    from taskrl.training import offpolicy

    pieces = {
        "update": (dqn.DQNAgent, "update"),
        "act": (base.Agent, "act"),
        "env step": (bitflip.BitFlip, "step"),
        "store": (storage.EpisodeReplay, "add"),
    }
    per_env_step = {"update": 1.0, "sample + relabel": 1.0, "act": 0.5, "env step": 0.5, "store": 0.5}  # 2 envs
    out, rows = {}, []
    for batch, hidden in ((32, (64, 64)), (256, (256, 256))):
        agent, one_batch, _ = bitflip_agent_and_batch(batch, hidden, False)
        flops = update_flops(agent, one_batch)
        _, sb3, _ = dqn_case(batch, hidden)
        sb3_run = sb3(0, args.loop_steps, 10**12, 0.0)
        sb3_ms = sb3_run["seconds"] / sb3_run["env_steps"] * 1e3
        for compile_mode in ("off", "default"):
            clock = _Clock(skip=300)
            originals = {name: getattr(owner, attr) for name, (owner, attr) in pieces.items()}
            sampler = offpolicy.batch_sampler
            try:
                for name, (owner, attr) in pieces.items():
                    setattr(owner, attr, clock.wrap(name, originals[name]))
                offpolicy.batch_sampler = functools.partial(_clocked_sampler, clock, sampler)
                settings = {**DQN_EQUAL, "batch_size": batch, "hidden_sizes": hidden, "updates_per_call": 1}
                r = taskrl_learn_until("bitflip-her", 0, args.loop_steps, 10**12, 0.0, compile=compile_mode, **settings)
            finally:
                for name, (owner, attr) in pieces.items():
                    setattr(owner, attr, originals[name])
                offpolicy.batch_sampler = sampler
            rate = matmul_rate()
            bound_ms = flops / rate * 1e3
            per = clock.ms_per_call()
            wall = (r["seconds"] - r["compile_seconds"]) / r["env_steps"] * 1e3
            parts = {name: per.get(name, 0.0) * share for name, share in per_env_step.items()}
            rest = wall - sum(parts.values())
            key = f"batch {batch}, {list(hidden)}, compile {compile_mode}"
            out[key] = {"per_call_ms": per, "calls": clock.calls, "run": r, "bound_ms": bound_ms, "sb3": sb3_run}
            rows.append(
                f"| {key} | {wall:.3f} | {parts['update']:.3f} ({bound_ms:.3f}) | "
                + " | ".join(f"{parts[name]:.3f}" for name in ("sample + relabel", "act", "env step", "store"))
                + f" | {rest:.3f} | {sb3_ms:.3f} | {sb3_ms / wall:.2f}x | {sb3_ms / bound_ms:.2f}x |"
            )
            print(rows[-1], flush=True)
    table = "\n".join(
        [
            f"DQN + HER on bit flipping n = 15 at the equal-work settings (2 envs, one update per env step), "
            f"{args.loop_steps:,} env steps, seed 0. ms per env step: each part's ms per call after its first 300 calls, "
            "times its calls per env step (one update and one sample; one act, env step and store per 2 env steps); "
            "the wall time leaves out the compile; the rest is the loop's own (the bookkeeping, the clocks' wrappers). "
            "In brackets: the update's matrix products at the matrix-multiply rate measured after the run (the bound). "
            "SB3: its whole step on the same case, as many env steps. Ceiling: SB3's step over the bound, the ratio "
            "to SB3 of a step that were only its update's matrix products.",
            "",
            "| run | wall ms per env step | update (bound) | sample + relabel | act | env step | store | rest | SB3's step "
            "| SB3 / taskrl | ceiling |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return table, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=["equal", "bound", "curves", "loop", "kernels", "one"])
    parser.add_argument("--loop-steps", type=int, default=8_000, help="loop: env steps of each timed run")
    parser.add_argument("--curve-cases", nargs="+", default=list(CURVE_CASES), choices=list(CURVE_CASES))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--cases", nargs="+", default=["dqn32", "dqn256", "sac"], choices=["dqn32", "dqn256", "sac"])
    parser.add_argument("--only", nargs="*", default=[], help="bound: only the cases whose names hold one of these words")
    parser.add_argument("--per-call", type=int, default=4, help="bound: updates per call in the K-updates column")
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument(
        "--libs",
        nargs="+",
        default=[],
        help="equal: only these arms beside sb3 (taskrl, 'taskrl compiled', 'taskrl, no flag', ...)",
    )
    parser.add_argument("--throughput-only", action="store_true", help="equal: skip the time-to-90%% runs")
    parser.add_argument(
        "--slice-seconds", type=float, default=0, help="equal: throughput runs of the env steps SB3 makes in about this long"
    )
    parser.add_argument("--title", default="", help="the RESULTS section's title (default: the mode's)")
    parser.add_argument("--throughput-steps", type=int, default=0, help="equal: env steps of each throughput run (0: the case's)")
    parser.add_argument("--reuse-log", type=Path, default=None, help="equal: an earlier run's output, whose results to keep")
    parser.add_argument(
        "--reuse-libs", nargs="*", default=["sb3"], help="equal: the libraries (or CASE/LIBRARY) whose earlier results to keep"
    )
    parser.add_argument("--seconds", type=float, default=6.0, help="bound: timing per case and path, over all rounds")
    parser.add_argument("--rounds", type=int, default=12, help="bound: rounds of the side-by-side timing")
    parser.add_argument("--one-compile", default="auto", help="one: the run's --compile")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (both libraries)")
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    parser.add_argument(
        "--json", type=Path, default=None, help="per-seed / per-case results (default results/learner_<mode>.json)"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    fresh_compile_cache()  # before anything compiles: the compile times measured are those of a first run
    if args.mode == "one":
        one(args)
        return
    table, data = {"equal": equal, "bound": bound, "curves": curves, "loop": loop, "kernels": kernels}[args.mode](args)
    path = args.json or RESULTS_DIR / f"learner_{args.mode}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2))
    print(table)
    if args.write:
        titles = {
            "equal": "Learner speed at equal work against Stable-Baselines3",
            "bound": "Learner speed against the FLOP bound",
            "curves": "Learning with compiled updates against eager ones",
            "loop": "Where the time of a training run goes: the off-policy loop's pieces",
            "kernels": "Where the time of a compiled DQN update goes: kernels against the bound",
        }
        append_results(
            args.title or titles[args.mode],
            f"torch threads = {args.threads}; raw data: `{path.relative_to(RESULTS_DIR.parent.parent) if path.is_absolute() else path}`.\n\n{table}",
        )


if __name__ == "__main__":
    main()
