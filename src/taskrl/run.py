"""A training run end to end: wiring, run directory, resume, and loading a trained agent.

Run directory layout::

    runs/<name>/
        config.json          the resolved configuration
        metrics.csv          one row per evaluation (columns in taskrl.logger)
        tensorboard/         TensorBoard events
        checkpoints/latest   name of the newest checkpoint folder
        checkpoints/step_*/  agent / replay / loop parts (safetensors + JSON)
        learning_curve.png   success rate against env steps and wall-clock
        per_task_success.json  multi-task runs: the last evaluation, per task (Meta-World's protocol)
"""

from __future__ import annotations

import dataclasses
import datetime
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from rich.console import Console

from taskrl import config as config_io
from taskrl.agents.dqn import DQNAgent
from taskrl.agents.ppo import PPOAgent
from taskrl.agents.qtopt import QTOptAgent
from taskrl.agents.sac import SACAgent
from taskrl.agents.td3 import TD3Agent
from taskrl.checkpoint import load_checkpoint, save_checkpoint
from taskrl.conditioning.networks import make_conditioning
from taskrl.config import GYMNASIUM_IDS, METAWORLD_BENCHMARKS, MULTITASK_ENVS, ON_POLICY_ALGOS, ConfigError, TrainConfig, validate, with_overrides
from taskrl.console import ConsoleReporter, final_table
from taskrl.envs import BitFlip, GymnasiumGoalEnv, MultiTaskPointReach, PointReach, evaluate_per_task, is_goal_env
from taskrl.envs.base import BatchedEnv
from taskrl.envs.multitask_point import DEFAULT_REGIONS
from taskrl.logger import RunLogger
from taskrl.plots import plot_learning_curve
from taskrl.presets import preset_config
from taskrl.replay import EpisodeReplay, HindsightRelabeler, TaskBalancedSampler
from taskrl.training.bookkeeping import StopRequest
from taskrl.training.evaluation import evaluate
from taskrl.training.offpolicy import LoopSchedule, LoopState, OffPolicyLoop
from taskrl.training.onpolicy import OnPolicyLoop, OnPolicySchedule

#: Observation keys the networks read, where the env has them (the task index is read separately).
AGENT_INPUT_KEYS = ("observation", "desired_goal")
Agent = DQNAgent | QTOptAgent | SACAgent | TD3Agent | PPOAgent
EVAL_SEED_OFFSET = 1_000_003


@dataclasses.dataclass
class Run:
    """The result of :func:`train`: where it was written, its settings, last metrics, and agent."""

    run_dir: Path
    config: TrainConfig
    metrics: dict[str, Any]
    agent: Agent
    stopped_by: str | None = None  # "time limit", "SIGINT", "SIGTERM" when stopped early (resumable)


# ---------------------------------------------------------------------- wiring
def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError("device", f"{name!r} requested but CUDA is not available; allowed here: cpu, auto")
    return torch.device(name)


def metaworld_benchmark(config: TrainConfig) -> tuple[str, str | None]:
    """``(benchmark, task)`` of a Meta-World run: ``("MT1", "reach")``, ``("MT10", None)``, ..."""
    benchmark = METAWORLD_BENCHMARKS[config.env]
    return benchmark, config.mt1_task if benchmark == "MT1" else None


def make_env(config: TrainConfig, num_envs: int, seed: int, device: torch.device, evaluation: bool = False) -> BatchedEnv:
    """The run's batched environment: a native torch one, or gymnasium's through the adapter.

    Multi-task evaluation envs give every copy a fixed task (per-task evaluation); Meta-World's
    evaluation env uses the training goal positions (Meta-World's protocol evaluates on them), one
    copy per task, and ``num_envs`` (training) must be a multiple of the number of tasks.
    """
    if config.env == "pointreach-mt":
        return MultiTaskPointReach(num_envs=num_envs, device=device, reward=config.reward,
                                   task_sampling="fixed" if evaluation else "uniform",
                                   terminate_on_success=config.terminate_on_success, seed=seed)
    if config.env in METAWORLD_BENCHMARKS:
        from taskrl.envs.metaworld_tasks import MetaWorldMultiTaskEnv, metaworld_task_set

        benchmark, task = metaworld_benchmark(config)
        num_tasks = len(metaworld_task_set(benchmark, task))
        return MetaWorldMultiTaskEnv(benchmark, task, use_one_hot=True,
                                     envs_per_task=1 if evaluation else max(1, num_envs // num_tasks),
                                     max_episode_steps=config.max_episode_steps, seed=config.seed, device=device,
                                     vector_strategy=config.vector_strategy)
    if config.env == "bitflip":
        return BitFlip(config.n_bits, num_envs=num_envs, device=device,
                       terminate_on_success=config.terminate_on_success, seed=seed)
    if config.env == "pointreach":
        return PointReach(num_envs=num_envs, device=device, reward=config.reward,
                          terminate_on_success=config.terminate_on_success, seed=seed)
    return GymnasiumGoalEnv(GYMNASIUM_IDS[config.env], num_envs=num_envs, device=device,
                            vector_strategy=config.vector_strategy, success_key="is_success")


def make_agent(config: TrainConfig, env: BatchedEnv, device: torch.device) -> Agent:
    """The agent of ``config.algo`` for ``env``'s spaces; a mismatch is a ConfigError naming ``algo``."""
    space = env.single_observation_space
    keys = tuple(k for k in AGENT_INPUT_KEYS if k in space.spaces)
    multitask = "task" in space.spaces
    if "observation" not in keys or not (multitask or "desired_goal" in keys):
        raise ConfigError("env", f"observations have keys {list(space.spaces)}; the agents here need 'observation' "
                                 f"and either 'desired_goal' (goal-conditioned) or 'task' (multi-task)")
    input_dim = sum(int(torch.tensor(space[k].shape).prod()) for k in keys)
    task_set = getattr(env, "task_set", None)
    conditioning = None
    if multitask and len(task_set) > 1:  # one task needs no context
        conditioning = make_conditioning(config.conditioning, len(task_set), task_set.descriptions)
    action_space = env.single_action_space
    discrete = isinstance(action_space, gym.spaces.Discrete)
    if config.algo == "ppo":  # Gaussian (Box) or categorical (Discrete) policy
        return PPOAgent(keys, input_dim, action_space, config.ppo, device, conditioning)
    if config.algo == "dqn":
        if not discrete:
            raise ConfigError("algo", f"dqn needs discrete actions but {config.env!r} has {action_space}; use qtopt or sac")
        return DQNAgent(keys, input_dim, int(action_space.n), config.dqn, device)
    if not isinstance(action_space, gym.spaces.Box):
        raise ConfigError("algo", f"{config.algo} needs continuous (Box) actions but {config.env!r} has {action_space}; use dqn")
    if config.algo == "sac":
        return SACAgent(keys, input_dim, action_space, config.sac, device, conditioning)
    agent_cls = {"qtopt": QTOptAgent, "td3": TD3Agent}[config.algo]
    return agent_cls(keys, input_dim, action_space, getattr(config, config.algo), device)


def make_evaluator(config: TrainConfig, eval_env: BatchedEnv, agent: Agent, seed: int):
    """``() -> metrics`` for the loop, and a holder of the last full result (per-task for multi-task envs).

    Goal-conditioned envs: success at the step an episode ends, over ``eval_episodes`` episodes.
    Multi-task envs: :func:`evaluate_per_task` with ``eval_episodes`` per task; Meta-World counts an
    episode as a success if it succeeds at any step (its protocol); the native multi-task
    PointReach at the final step (touring several regions must not count). ``success_rate`` is
    the mean over tasks and every task adds a ``success/<name>`` column.
    """
    last: dict[str, Any] = {}
    policy = lambda o: agent.act(o)  # noqa: E731 (greedy: exploration 0)

    def run() -> dict[str, float]:
        if config.env not in MULTITASK_ENVS:
            return evaluate(policy, eval_env, seed)
        result = evaluate_per_task(policy, eval_env, config.eval_episodes, seed,
                                   success="final" if config.env == "pointreach-mt" else "any")
        last.clear(), last.update(result)
        tasks = result["tasks"].values()
        return {
            "success_rate": result["mean_success_rate"],
            "eval_return": sum(t["mean_return"] for t in tasks) / len(tasks),
            "eval_length": sum(t["mean_length"] for t in tasks) / len(tasks),
            **{f"success/{name}": t["success_rate"] for name, t in result["tasks"].items()},
        }

    return run, last


def eval_env_copies(config: TrainConfig) -> int:
    """Copies of the evaluation env: one episode each (goal envs), every task ``eval_episodes`` times at once
    (native multi-task), or Meta-World's one copy per task."""
    if config.env == "pointreach-mt":
        return len(DEFAULT_REGIONS) * config.eval_episodes
    return config.eval_episodes


def make_relabeler(config: TrainConfig, env: BatchedEnv) -> HindsightRelabeler | None:
    if config.her == "none":
        return None
    if not is_goal_env(env):
        raise ConfigError("her", f"hindsight relabelling needs a goal env (achieved_goal, desired_goal, compute_reward); "
                                 f"{config.env!r} is not one; use --her none")
    return HindsightRelabeler(env.compute_reward, config.her, config.her_k,
                              terminated_fn=getattr(env, "compute_terminated", None))


def default_run_dir(preset: str) -> Path:
    return Path("runs") / f"{preset}-{datetime.datetime.now():%Y%m%d-%H%M%S}"


# ---------------------------------------------------------------------- training
def train(
    preset: str | None = "bitflip-her",
    *,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    progress: bool = False,
    tensorboard: bool = True,
    console: Console | None = None,
    **overrides: Any,
) -> Run:
    """Train a preset (with overrides), or continue a run directory.

    Args:
        preset: name from ``taskrl presets``; ignored when resuming.
        out: run directory (default ``runs/<preset>-<timestamp>``); must not hold a run already.
        resume: a run directory to continue from its last checkpoint, with its saved settings
            (``overrides`` still apply, e.g. a larger ``total_steps``).
        progress: show a progress bar and print the final table.
        tensorboard: write TensorBoard events.
        console: where the final table goes (default stderr).
        **overrides: any setting of :class:`taskrl.config.TrainConfig` by name (``n_bits=30``).

    Returns:
        a :class:`Run` with the run directory, configuration, final metrics and trained agent.
    """
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / "config.json").exists():
            raise ConfigError("resume", f"{run_dir} is not a run directory (no config.json)")
        config = validate(with_overrides(config_io.load(run_dir / "config.json"), overrides))
    else:
        config = validate(with_overrides(preset_config(preset), overrides))
        run_dir = Path(out) if out is not None else default_run_dir(preset)
        if (run_dir / "checkpoints").exists():
            raise ConfigError("out", f"{run_dir} already holds a run; pass --resume {run_dir} to continue it")
    run_dir.mkdir(parents=True, exist_ok=True)
    config_io.save(config, run_dir / "config.json")

    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    env = make_env(config, config.num_envs, config.seed, device)
    eval_env = make_env(config, eval_env_copies(config), config.seed + EVAL_SEED_OFFSET, device, evaluation=True)
    agent = make_agent(config, env, device)
    on_policy = config.algo in ON_POLICY_ALGOS
    relabel = make_relabeler(config, env)
    replay = None if on_policy else EpisodeReplay(
        env.single_observation_space, env.single_action_space,
        min(config.buffer_size, config.total_steps + 2 * env.num_envs * env.horizon), env.horizon, env.num_envs, device)
    sampler = TaskBalancedSampler(replay, len(env.task_set)) if config.sampling == "task_balanced" and replay else None
    generator = torch.Generator(device=device)
    generator.manual_seed(config.seed + 1)

    state = LoopState(next_checkpoint=config.checkpoint_interval)
    if resume is not None:
        saved = load_checkpoint(run_dir / "checkpoints", ("agent", "replay", "loop"), device)
        agent.load_state_dict(saved["agent"])
        if "replay" in saved and replay is not None:
            replay.load_state_dict(saved["replay"])
        loop_saved = dict(saved["loop"])
        generator.set_state(loop_saved.pop("generator").cpu())
        state = LoopState(**loop_saved)

    logger = RunLogger(run_dir, tensorboard=tensorboard, resume_from_step=state.env_steps if resume else None)

    def checkpoint(loop_state: LoopState) -> None:
        parts: dict[str, Any] = {
            "agent": agent.state_dict(),
            "loop": {**dataclasses.asdict(loop_state), "generator": generator.get_state()},
        }
        if config.save_replay and replay is not None:
            parts["replay"] = replay.state_dict()
        save_checkpoint(run_dir / "checkpoints", parts, loop_state.env_steps)

    rows: list[dict[str, Any]] = []
    title = preset or f"{config.env}-{config.algo}"
    with ConsoleReporter(title, config.total_steps, state.env_steps, enabled=progress) as reporter:

        def on_log(row: dict[str, Any]) -> None:
            rows.append(row)
            logger.log(row)
            reporter.update(row)

        evaluator, last_eval = make_evaluator(config, eval_env, agent, config.seed + EVAL_SEED_OFFSET)
        stop = StopRequest(config.max_hours)
        callbacks = dict(evaluate=evaluator, on_log=on_log, on_checkpoint=checkpoint, generator=generator, stop=stop)
        if on_policy:
            loop = OnPolicyLoop(env, agent, OnPolicySchedule(config.total_steps, config.eval_interval,
                                                             config.checkpoint_interval, config.stop_at_success), **callbacks)
        else:
            schedule = LoopSchedule(
                total_steps=config.total_steps, batch_size=config.batch_size, learning_starts=config.learning_starts,
                updates_per_step=config.updates_per_step, eval_interval=config.eval_interval,
                checkpoint_interval=config.checkpoint_interval, stop_at_success=config.stop_at_success,
                epsilon_start=config.epsilon_start, epsilon_end=config.epsilon_end,
                epsilon_decay_steps=config.epsilon_decay_steps,
            )
            loop = OffPolicyLoop(env, agent, replay, relabel, schedule, sample=sampler, **callbacks)
        try:
            with stop.on_signals():
                state = loop.run(state, env_seed=config.seed + state.env_steps)
        finally:
            logger.close()
            env.close()
            eval_env.close()

    curve = plot_learning_curve(logger.path, run_dir / "learning_curve.png", title=f"{title} ({run_dir.name})")
    if last_eval:  # multi-task: the per-task table of the last evaluation, printed and saved
        from taskrl.envs.metaworld_tasks import per_task_table

        (run_dir / "per_task_success.json").write_text(json.dumps({"env_steps": state.env_steps, **last_eval}, indent=2) + "\n")
        if progress:
            (console or Console(stderr=True)).print(per_task_table(last_eval, f"per-task success at {state.env_steps:,} env steps"))
    final = rows[-1] if rows else {"env_steps": state.env_steps, "updates": state.updates,
                                   "wall_seconds": state.wall_seconds, "success_rate": state.last_success}
    if progress:
        (console or Console(stderr=True)).print(final_table({"eval_return": float("nan"), **final}, run_dir, curve))
    if stop.stopped_by:
        (console or Console(stderr=True)).print(
            f"stopped early ({stop.stopped_by}) at {state.env_steps:,} env steps, checkpoint saved; "
            f"continue with: taskrl train --resume {run_dir}", soft_wrap=True, markup=False)
    return Run(run_dir=run_dir, config=config, metrics=final, agent=agent, stopped_by=stop.stopped_by)


# ---------------------------------------------------------------------- loading
def load(run_dir: str | Path, device: str = "cpu") -> Agent:
    """The trained agent of a run directory; ``agent.act(obs)`` takes the environment's observations.

    Only safetensors and JSON are read: loading never executes code.
    """
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").exists():
        raise ConfigError("run_dir", f"{run_dir} is not a run directory (no config.json)")
    config = config_io.load(run_dir / "config.json")
    dev = resolve_device(device)
    if config.env in METAWORLD_BENCHMARKS:  # spaces and task set only: building Meta-World takes seconds
        from taskrl.envs.metaworld_tasks import metaworld_spec

        env = metaworld_spec(*metaworld_benchmark(config))
    else:
        env = make_env(config, 1, 0, dev, evaluation=True)
    agent = make_agent(config, env, dev)
    env.close()
    agent.load_state_dict(load_checkpoint(run_dir / "checkpoints", ("agent",), dev)["agent"])
    return agent


def evaluate_run(run_dir: str | Path, episodes: int = 100, seed: int | None = None, device: str = "cpu") -> dict[str, float]:
    """Re-evaluate a saved agent greedily on ``episodes`` fresh episodes (per task on multi-task envs)."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").exists():
        raise ConfigError("run_dir", f"{run_dir} is not a run directory (no config.json)")
    config = dataclasses.replace(config_io.load(run_dir / "config.json"), eval_episodes=episodes)
    try:  # before loading anything
        validate(config)
    except ConfigError as error:  # the only setting this call changes is the episode count
        raise ConfigError("episodes" if error.field == "eval_episodes" else error.field, error.message) from None
    agent = load(run_dir, device)
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else seed
    env = make_env(config, eval_env_copies(config), seed, agent.device, evaluation=True)
    try:
        return {**make_evaluator(config, env, agent, seed)[0](), "episodes": episodes}
    finally:
        env.close()
