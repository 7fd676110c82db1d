"""A training run end to end: wiring, run directory, resume, and loading a trained agent.

Run directory layout::

    runs/<name>/
        config.json          the resolved configuration
        metrics.csv          one row per evaluation (columns in taskrl.logger)
        tensorboard/         TensorBoard events
        checkpoints/latest   name of the newest checkpoint folder
        checkpoints/step_*/  agent / replay / loop parts (safetensors + JSON)
        learning_curve.png   success rate against env steps and wall-clock
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from rich.console import Console

from taskrl import config as config_io
from taskrl.agents.dqn import DQNAgent
from taskrl.agents.qtopt import QTOptAgent
from taskrl.agents.sac import SACAgent
from taskrl.agents.td3 import TD3Agent
from taskrl.checkpoint import load_checkpoint, save_checkpoint
from taskrl.config import GYMNASIUM_IDS, ConfigError, TrainConfig, validate, with_overrides
from taskrl.console import ConsoleReporter, final_table
from taskrl.envs import BitFlip, GymnasiumGoalEnv, PointReach, is_goal_env
from taskrl.envs.base import BatchedEnv
from taskrl.logger import RunLogger
from taskrl.plots import plot_learning_curve
from taskrl.presets import preset_config
from taskrl.replay import EpisodeReplay, HindsightRelabeler
from taskrl.training.evaluation import evaluate
from taskrl.training.offpolicy import LoopSchedule, LoopState, OffPolicyLoop

AGENT_INPUT_KEYS = ("observation", "desired_goal")
Agent = DQNAgent | QTOptAgent | SACAgent | TD3Agent
EVAL_SEED_OFFSET = 1_000_003


@dataclasses.dataclass
class Run:
    """The result of :func:`train`: where it was written, its settings, last metrics, and agent."""

    run_dir: Path
    config: TrainConfig
    metrics: dict[str, Any]
    agent: Agent


# ---------------------------------------------------------------------- wiring
def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError("device", f"{name!r} requested but CUDA is not available; allowed here: cpu, auto")
    return torch.device(name)


def make_env(config: TrainConfig, num_envs: int, seed: int, device: torch.device) -> BatchedEnv:
    """The run's batched environment: a native torch one, or gymnasium's through the adapter."""
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
    missing = [k for k in AGENT_INPUT_KEYS if k not in space.spaces]
    if missing:
        raise ConfigError("env", f"observations lack {missing}; the agents here need keys {list(AGENT_INPUT_KEYS)}")
    input_dim = sum(int(torch.tensor(space[k].shape).prod()) for k in AGENT_INPUT_KEYS)
    action_space = env.single_action_space
    discrete = isinstance(action_space, gym.spaces.Discrete)
    if config.algo == "dqn":
        if not discrete:
            raise ConfigError("algo", f"dqn needs discrete actions but {config.env!r} has {action_space}; use qtopt or sac")
        return DQNAgent(AGENT_INPUT_KEYS, input_dim, int(action_space.n), config.dqn, device)
    if not isinstance(action_space, gym.spaces.Box):
        raise ConfigError("algo", f"{config.algo} needs continuous (Box) actions but {config.env!r} has {action_space}; use dqn")
    agent_cls = {"qtopt": QTOptAgent, "sac": SACAgent, "td3": TD3Agent}[config.algo]
    agent_config = getattr(config, config.algo)
    return agent_cls(AGENT_INPUT_KEYS, input_dim, action_space, agent_config, device)


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
    eval_env = make_env(config, config.eval_episodes, config.seed + EVAL_SEED_OFFSET, device)
    agent = make_agent(config, env, device)
    relabel = make_relabeler(config, env)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space,
                           min(config.buffer_size, config.total_steps + config.num_envs * env.horizon),
                           env.horizon, config.num_envs, device)
    generator = torch.Generator(device=device)
    generator.manual_seed(config.seed + 1)

    state = LoopState(next_checkpoint=config.checkpoint_interval)
    if resume is not None:
        saved = load_checkpoint(run_dir / "checkpoints", ("agent", "replay", "loop"), device)
        agent.load_state_dict(saved["agent"])
        if "replay" in saved:
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
        if config.save_replay:
            parts["replay"] = replay.state_dict()
        save_checkpoint(run_dir / "checkpoints", parts, loop_state.env_steps)

    schedule = LoopSchedule(
        total_steps=config.total_steps, batch_size=config.batch_size, learning_starts=config.learning_starts,
        updates_per_step=config.updates_per_step, eval_interval=config.eval_interval,
        checkpoint_interval=config.checkpoint_interval, stop_at_success=config.stop_at_success,
        epsilon_start=config.epsilon_start, epsilon_end=config.epsilon_end,
        epsilon_decay_steps=config.epsilon_decay_steps,
    )
    rows: list[dict[str, Any]] = []
    title = preset or f"{config.env}-{config.algo}"
    with ConsoleReporter(title, config.total_steps, state.env_steps, enabled=progress) as reporter:

        def on_log(row: dict[str, Any]) -> None:
            rows.append(row)
            logger.log(row)
            reporter.update(row)

        loop = OffPolicyLoop(env, agent, replay, relabel, schedule,
                             evaluate=lambda: evaluate(lambda o: agent.act(o), eval_env, config.seed + EVAL_SEED_OFFSET),
                             on_log=on_log, on_checkpoint=checkpoint, generator=generator)
        try:
            state = loop.run(state, env_seed=config.seed + state.env_steps)
        finally:
            logger.close()
            env.close()
            eval_env.close()

    curve = plot_learning_curve(logger.path, run_dir / "learning_curve.png", title=f"{title} ({run_dir.name})")
    final = rows[-1] if rows else {"env_steps": state.env_steps, "updates": state.updates,
                                   "wall_seconds": state.wall_seconds, "success_rate": state.last_success}
    if progress:
        (console or Console(stderr=True)).print(final_table({"eval_return": float("nan"), **final}, run_dir, curve))
    return Run(run_dir=run_dir, config=config, metrics=final, agent=agent)


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
    env = make_env(config, 1, 0, dev)
    agent = make_agent(config, env, dev)
    env.close()
    agent.load_state_dict(load_checkpoint(run_dir / "checkpoints", ("agent",), dev)["agent"])
    return agent


def evaluate_run(run_dir: str | Path, episodes: int = 100, seed: int | None = None, device: str = "cpu") -> dict[str, float]:
    """Re-evaluate a saved agent greedily on ``episodes`` fresh episodes."""
    run_dir = Path(run_dir)
    agent = load(run_dir, device)
    config = config_io.load(run_dir / "config.json")
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else seed
    env = make_env(config, episodes, seed, agent.device)
    try:
        return {**evaluate(lambda o: agent.act(o), env, seed), "episodes": episodes}
    finally:
        env.close()
