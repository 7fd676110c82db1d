"""A training run end to end: build its parts, restore them, run the loop, report; load a trained agent.

Run directory layout::

    runs/<name>/
        config.json          the resolved configuration
        metrics.csv          one row per evaluation (columns in taskrl.logger)
        tensorboard/         TensorBoard events
        checkpoints/latest   name of the newest checkpoint folder
        checkpoints/step_*/  agent / replay / loop parts (safetensors + JSON)
        learning_curve.png   success rate against env steps and wall-clock
        per_task_success.json  multi-task runs: the last evaluation, per task
        tasks.json           runs on a TaskSet given in Python: its tasks

Everything env- or algorithm-specific comes from the registries (``taskrl.envs.registry``,
``taskrl.agents.registry``): this file names no environment and no algorithm.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import importlib
import json
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from rich.console import Console

from taskrl import config as config_io
from taskrl.agents.registry import algorithm
from taskrl.agents.spec import AgentInputs
from taskrl.checkpoint import checkpoint_at, checkpoint_step, load_checkpoint, read_checkpoint, save_checkpoint
from taskrl.conditioning.networks import make_conditioning
from taskrl.config import TrainConfig, check_device, check_fit, validate, with_overrides
from taskrl.console import ConsoleReporter, final_table, per_task_table
from taskrl.distributed.limiter import UpdateToDataLimiter
from taskrl.distributed.loop import CALLS_PER_COLLECTOR, DistributedLoop
from taskrl.distributed.roles import BellmanUpdater, Collector
from taskrl.envs.base import BatchedEnv
from taskrl.envs.registry import ENV_FAMILIES, env_family, family_for_source
from taskrl.envs.reward_tasks import parse_qualities
from taskrl.envs.spec import EnvFamily, EnvRequest, env_kind
from taskrl.errors import ConfigError, reason, require
from taskrl.logger import RunLogger, require_wandb
from taskrl.plots import plot_learning_curve
from taskrl.presets import preset_config
from taskrl.replay import EpisodeReplay, HindsightRelabeler, RecentMixSampler, TaskBalancedSampler
from taskrl.replay.storage import saved_episodes
from taskrl.rundir import RunLock, atomic_write_text, check_new_run_dir
from taskrl.sharing import TaskSharing, collect_task_datasets
from taskrl.sharing.strategies import task_functions
from taskrl.training.bookkeeping import Bookkeeping, LoopState, StopRequest
from taskrl.training.evaluation import ActingPolicy, evaluate
from taskrl.training.offline import OfflineLoop
from taskrl.training.offpolicy import LoopSchedule, OffPolicyLoop, batch_sampler
from taskrl.training.onpolicy import OnPolicyLoop
from taskrl.training.per_task import evaluate_per_task

__all__ = ["Run", "RunParts", "RunSpaces", "build", "evaluate_run", "load", "load_run", "make_agent", "make_env", "train"]

#: Observation keys the networks read, where the env has them (the task index is read separately).
AGENT_INPUT_KEYS = ("observation", "desired_goal")
EVAL_SEED_OFFSET = 1_000_003
DATASET_SEED_OFFSET = 2_000_003


@dataclasses.dataclass
class Run:
    """The result of :func:`train`: where it was written, its settings, last metrics, and agent.

    Attributes:
        notes: what changing ``env`` or ``algo`` on a preset kept or dropped (also printed).
    """

    run_dir: Path
    config: TrainConfig
    metrics: dict[str, Any]
    agent: Any
    stopped_by: str | None = None  # "time limit", "SIGINT", "SIGTERM" when stopped early (resumable)
    notes: list[str] = dataclasses.field(default_factory=list)


# ---------------------------------------------------------------------- wiring
def resolve_device(name: str) -> torch.device:
    """``cpu``, ``cuda``, ``cuda:N`` or ``auto``; a :class:`ConfigError` for any other name or absent CUDA."""
    check_device(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError("device", f"{name!r} requested but CUDA is not available; allowed here: cpu, auto")
    return torch.device(name)


def action_kind(space: gym.spaces.Space) -> str | None:
    """``discrete``, ``box`` or None (a space no algorithm here acts in)."""
    if isinstance(space, gym.spaces.Discrete):
        return "discrete"
    return "box" if isinstance(space, gym.spaces.Box) else None


def env_request(
    config: TrainConfig, device: torch.device, source: Any = None, evaluation: bool = False, seed: int | None = None
) -> EnvRequest:
    """What the run asks of its env family (training envs, or the evaluation env)."""
    if seed is None:
        seed = config.seed + EVAL_SEED_OFFSET if evaluation else config.seed
    return EnvRequest(
        num_envs=config.num_envs,
        seed=seed,
        device=device,
        evaluation=evaluation,
        eval_episodes=config.eval_episodes,
        run_seed=config.seed,
        source=source,
    )


def make_env(
    config: TrainConfig,
    device: str | torch.device = "cpu",
    num_envs: int | None = None,
    seed: int | None = None,
    evaluation: bool = False,
    source: Any = None,
) -> BatchedEnv:
    """The run's training env (or, with ``evaluation``, its evaluation env), built by its env family.

    Args:
        config: a validated configuration.
        device: where the env's tensors live.
        num_envs: training copies (default ``config.num_envs``).
        seed: the env's seed (default the run's, or its evaluation seed).
        evaluation: the evaluation env (one copy per episode, or fixed tasks per copy).
        source: the Python object (factory, TaskSet) the run's family builds from, if any.
    """
    request = env_request(config, torch.device(device), source, evaluation, seed)
    if num_envs is not None:
        request = dataclasses.replace(request, num_envs=num_envs)
    return env_family(config.env).make(config.env_settings, request)


def make_agent(config: TrainConfig, env: Any, device: torch.device) -> Any:
    """The agent of ``config.algo`` for ``env``'s spaces (an env, or an object with its spaces).

    The env is checked against the algorithm with the same rules as before building
    (:func:`taskrl.config.check_fit`), now with the env's real kind and action space.
    """
    check_fit(config, env_kind(env), action_kind(env.single_action_space))
    if action_kind(env.single_action_space) is None:
        raise ConfigError("env", f"actions must be Box or Discrete; {config.env!r} has {env.single_action_space}")
    space = env.single_observation_space
    keys = tuple(k for k in AGENT_INPUT_KEYS if k in space.spaces)
    if "observation" not in keys:
        raise ConfigError(
            "env",
            f"observations have keys {list(space.spaces)}; the networks read 'observation' "
            f"(with 'desired_goal' on goal envs and 'task' on multi-task envs)",
        )
    input_dim = sum(int(torch.tensor(space[k].shape).prod()) for k in keys)
    task_set = getattr(env, "task_set", None)
    conditioning = None
    if env_kind(env) == "multitask" and task_set is not None and len(task_set) > 1:  # one task needs no context
        conditioning = make_conditioning(config.conditioning, len(task_set), task_set.descriptions)
    check_network_memory(config, input_dim, device)
    inputs = AgentInputs(keys, input_dim, env.single_action_space)
    return algorithm(config.algo).build(inputs, config.algo_settings, device, conditioning)


def make_evaluator(
    config: TrainConfig, eval_env: BatchedEnv, agent: Any, seed: int, stochastic: bool = False, details: bool = False
):
    """``() -> metrics`` for the loop, and a holder of the last full result (per-task for multi-task envs).

    Single-task envs: success at the step an episode ends, one episode per evaluation copy.
    Multi-task envs: :func:`evaluate_per_task` with ``eval_episodes`` per task and the family's
    success criterion (any step on Meta-World, its protocol; the final step on the native
    multi-task PointReach, where touring regions must not count). ``success_rate`` is the mean
    over tasks and every task adds a ``success/<name>`` column.
    """
    last: dict[str, Any] = {}
    multitask = env_kind(eval_env) == "multitask"
    # once, not at every evaluation (a task set's criterion reads its task file)
    criterion = env_family(config.env).success_criterion(config.env_settings) if multitask else None

    policy = ActingPolicy(agent, explore=stochastic)  # greedy unless asked to explore

    def run() -> dict[str, float]:
        if not multitask:
            return evaluate(policy, eval_env, seed, details=details)
        result = evaluate_per_task(policy, eval_env, config.eval_episodes, seed, success=criterion)
        last.clear(), last.update(result)
        tasks = result["tasks"].values()
        return {
            "success_rate": result["mean_success_rate"],
            "eval_return": sum(t["mean_return"] for t in tasks) / len(tasks),
            "eval_length": sum(t["mean_length"] for t in tasks) / len(tasks),
            **{f"success/{name}": t["success_rate"] for name, t in result["tasks"].items()},
        }

    return run, last


def make_relabeler(config: TrainConfig, env: BatchedEnv) -> HindsightRelabeler | None:
    if config.her == "none":
        return None
    return HindsightRelabeler(
        env.compute_reward, config.her, config.her_k, terminated_fn=getattr(env, "compute_terminated", None)
    )


@dataclasses.dataclass
class RunParts:
    """Everything a run is made of, built from its config (:func:`build`)."""

    config: TrainConfig
    family: EnvFamily
    device: torch.device
    env: BatchedEnv
    eval_env: BatchedEnv
    agent: Any
    generator: torch.Generator
    replay: EpisodeReplay | None = None
    relabel: HindsightRelabeler | None = None
    sampler: Any = None
    #: the task-sharing sampler of a multi-task run whose env scores any task (inside ``sampler``)
    sharing: TaskSharing | None = None
    source: Any = None
    #: called when the run ends, newest first (a distributed run's actors and its local Ray)
    on_close: list[Callable[[], Any]] = dataclasses.field(default_factory=list)

    def close(self) -> None:
        try:
            for close in reversed(self.on_close):
                close()
        finally:
            self.env.close()
            self.eval_env.close()


def build(config: TrainConfig, source: Any = None) -> RunParts:
    """Envs, agent, replay, relabeller and sampler of a validated config (``source``: a Python
    object the env family builds its envs from, e.g. a factory or a TaskSet)."""
    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    family = env_family(config.env)
    offline = algorithm(config.algo).loop == "offline"
    if offline and family.spec is not None and source is None:  # trains from a dataset: spaces, no env to step
        env = family.spec(config.env_settings, env_request(config, device))
    elif config.cluster.distributed:  # collectors step the envs; the trainer's copy gives spaces and rewards
        env = make_env(config, device, num_envs=1, source=source)
    else:
        env = make_env(config, device, source=source)
    eval_env = None
    try:
        eval_env = make_env(config, device, evaluation=True, source=source)
        agent = make_agent(config, env, device)
        if config.compile != "off":
            agent.compile(config.compile)
        generator = torch.Generator(device=device)
        generator.manual_seed(config.seed + 1)
        parts = RunParts(config, family, device, env, eval_env, agent, generator, source=source)
        if algorithm(config.algo).loop == "off_policy":
            capacity = min(config.buffer_size, replay_needs(config, env))
            horizon = getattr(env, "horizon", None)
            check_replay_memory(
                EpisodeReplay.bytes_needed(
                    env.single_observation_space, env.single_action_space, capacity, num_envs=env.num_envs, horizon=horizon
                ),
                capacity,
                device,
            )
            parts.replay = EpisodeReplay(
                env.single_observation_space,
                env.single_action_space,
                capacity,
                num_envs=env.num_envs,
                device=device,
                horizon=horizon,
            )
            parts.relabel = make_relabeler(config, env)
            if config.sampling == "task_balanced":
                # a recent window mixes with plain task-balanced draws (validate() refuses it beside a strategy)
                sharing = _task_sharing(config, env, agent, parts.replay) if config.recent_fraction == 0 else None
                parts.sampler = parts.sharing = sharing
                if parts.sampler is None:
                    parts.sampler = TaskBalancedSampler(parts.replay, len(env.task_set))
            if config.recent_fraction > 0:
                balanced = parts.sampler.indices if parts.sampler is not None else None
                parts.sampler = RecentMixSampler(parts.replay, config.recent_fraction, config.recent_episodes, balanced)
        if offline:
            parts.sampler = _dataset_sampler(config, env, agent, device)
        if config.cluster.distributed:  # before anything is written: an unreachable cluster is one line
            from taskrl.distributed.actors import start_ray

            if start_ray(config.cluster, config.cluster.collectors + config.cluster.bellman_updaters):
                import ray

                parts.on_close.append(ray.shutdown)
        return parts
    except BaseException:
        env.close()
        if eval_env is not None:
            eval_env.close()
        raise


def _task_sharing(config: TrainConfig, env: BatchedEnv, agent: Any, replay: EpisodeReplay) -> TaskSharing | None:
    """Task-balanced batches with the run's sharing strategy, on an env that scores any task; None
    (plain task-balanced sampling) on one that cannot, where ``--sharing`` other than none is an error."""
    strategy = config.data_sharing.sharing
    if not task_functions(env):
        require(
            strategy == "none",
            "sharing",
            f"needs an env whose tasks are reward functions (task_reward, task_terminated, task_success); "
            f"{config.env!r} has none; allowed envs: gridtasks, pointtasks",
        )
        return None
    q_value = getattr(agent, "q_value", None)
    require(
        strategy != "conservative" or q_value is not None,
        "sharing",
        f"conservative ranks shared data by Q-values; {config.algo} has no q_value; use dqn or sac",
    )
    return TaskSharing(replay, env, len(env.task_set), config.data_sharing, q_value)


def _dataset_copies(steps: int) -> int:
    """Env copies per task that make a dataset of ``steps`` transitions (each copy ~40 steps or more)."""
    return max(1, min(50, steps // 40))


def dataset_steps(config: TrainConfig, env: Any) -> int:
    """Transitions of the env's offline datasets (``--dataset-quality``): 0 without any. Each task's
    ``dataset_steps`` is rounded up to a multiple of its env copies (all copies step together)."""
    settings = config.env_settings
    if not getattr(settings, "dataset_quality", ""):
        return 0
    copies = _dataset_copies(settings.dataset_steps)
    return len(env.task_set) * -(-settings.dataset_steps // copies) * copies


def check_preload_fits(replay: EpisodeReplay, transitions: int, what: str) -> None:
    """A :class:`ConfigError` on ``buffer_size`` when ``transitions`` more would evict stored data: a
    preload is never cut silently."""
    needed = replay.num_transitions + transitions
    require(
        needed <= replay.capacity,
        "buffer_size",
        f"{what} holds {transitions:,} transitions; the replay holds {replay.capacity:,}: use --buffer-size {needed:,} or more",
    )


def preload_datasets(parts: RunParts) -> int:
    """Store the env family's per-task datasets of the qualities ``--dataset-quality`` names; transitions stored."""
    config, env = parts.config, parts.env
    settings = config.env_settings
    qualities = parse_qualities(settings.dataset_quality, env.task_set.names)
    request = env_request(config, parts.device, parts.source, evaluation=True, seed=config.seed + DATASET_SEED_OFFSET)
    # the family's evaluation env: fixed tasks per copy, _dataset_copies of each
    maker = env_family(config.env).make(
        settings, dataclasses.replace(request, eval_episodes=_dataset_copies(settings.dataset_steps))
    )
    try:
        require(
            callable(getattr(maker, "expert_action", None)) and getattr(maker, "slot_tasks", None) is not None,
            "dataset_quality",
            f"{config.env!r} has no scripted expert to make datasets with; allowed envs: gridtasks, pointtasks",
        )
        check_preload_fits(parts.replay, dataset_steps(config, env), "--dataset-quality's datasets")
        episodes = collect_task_datasets(maker, qualities, settings.dataset_steps, config.seed)
    finally:
        maker.close()
    check_preload_fits(parts.replay, episodes.num_transitions, "--dataset-quality's datasets")
    parts.replay.add_episodes(episodes)
    return episodes.num_transitions


def replay_needs(config: TrainConfig, env: BatchedEnv) -> int:
    """Transitions a run can store: its datasets and env steps, the last step of every copy past
    ``total_steps`` included (with ``--offline-data``, also the other run's: everything up to ``buffer_size``).
    The episodes running at the end are stored cut (their steps are env steps already counted)."""
    if config.offline_data:
        return config.buffer_size
    stored = dataset_steps(config, env)
    if config.offline:
        return max(stored, 1)
    cluster = config.cluster
    if cluster.distributed:  # collect calls in flight may pass total_steps
        each = cluster.envs_each(config.num_envs)
        return config.total_steps + stored + cluster.collectors * each * CALLS_PER_COLLECTOR * cluster.collector_steps
    return config.total_steps + stored + env.num_envs


def _dataset_sampler(config: TrainConfig, env: Any, agent: Any, device: torch.device) -> Any:
    """An offline run's batches: its dataset (``dataset`` of the algorithm's settings), restricted to the
    env's tasks in the env's order, handed to the agent (which returns its sampler)."""
    from taskrl.demos.dataset import read_demonstrations

    path = getattr(config.algo_settings, "dataset", "")
    if not path:
        raise ConfigError(
            "dataset", "an offline algorithm learns from a dataset: --dataset DIR (make one with: taskrl demos collect)"
        )
    if not Path(path).exists():
        raise ConfigError("dataset", f"{path} does not exist; make it with: taskrl demos collect {config.env} --out {path}")
    demos = read_demonstrations(path, device)
    task_set = getattr(env, "task_set", None)
    if task_set is not None:
        demos = demos.select_tasks(task_set.names)
    return agent.use_dataset(demos)


def preload_replay(parts: RunParts, run_dir: str | Path) -> int:
    """Fill the replay with the stored episodes of another run's last checkpoint (``--offline-data``);
    how many episodes it now holds."""
    folder = Path(run_dir) / "checkpoints"
    try:
        saved = load_checkpoint(folder, ("replay",), parts.device)
    except (OSError, KeyError, ValueError, RuntimeError) as error:
        raise ConfigError(
            "offline_data",
            f"{run_dir} has no checkpoint with a replay to start from ({reason(error)}); train it with --save-replay",
        ) from None
    if "replay" not in saved:
        raise ConfigError("offline_data", f"the last checkpoint of {run_dir} holds no replay; train it with --save-replay")
    try:
        episodes, _ = saved_episodes(saved["replay"])
    except (KeyError, RuntimeError, ValueError, IndexError) as error:
        raise ConfigError("offline_data", f"the replay of {run_dir} cannot be read: {reason(error)}") from None
    check_preload_fits(parts.replay, episodes.num_transitions, f"--offline-data {run_dir}")
    try:
        parts.replay.add_episodes(episodes.to(parts.device))
    except (KeyError, RuntimeError, ValueError, IndexError) as error:
        raise ConfigError("offline_data", f"the replay of {run_dir} does not fit this run's env: {reason(error)}") from None
    return parts.replay.num_episodes


def _first_evaluation(config: TrainConfig) -> int:
    """Where a new run first evaluates: at its first step, except offline, where the untrained policy
    says nothing the dataset does not and a multi-task evaluation costs minutes."""
    return config.eval_interval if algorithm(config.algo).loop == "offline" else 0


def progress_axis(config: TrainConfig) -> str:
    """What a run's ``total_steps`` counts: ``env_steps``, or ``updates`` for an offline algorithm."""
    return "updates" if algorithm(config.algo).loop == "offline" or config.offline else "env_steps"


def available_memory(device: torch.device) -> int | None:
    """Bytes free for a new allocation on ``device`` (None where it cannot be read)."""
    if device.type == "cuda":
        return int(torch.cuda.mem_get_info(device)[0])
    try:
        with open("/proc/meminfo") as f:
            info = dict(line.split(":", 1) for line in f)
        return int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return None


def check_network_memory(config: TrainConfig, input_dim: int, device: torch.device) -> None:
    """A :class:`ConfigError` before allocating networks that cannot fit (a hand-edited ``config.json`` whose env
    settings imply millions of inputs): the first layers alone, with their targets and optimiser states."""
    width = max(getattr(config.algo_settings, "hidden_sizes", None) or (256,))
    needed = 8 * 4 * input_dim * width  # ~8 copies of the widest first layer (critics, targets, Adam moments), float32
    free = available_memory(device)
    if free is not None and needed > 0.5 * free:
        raise ConfigError(
            "env",
            f"{config.env!r} observations of {input_dim:,} values make networks of {needed / 2**30:.1f} GiB; "
            f"{free / 2**30:.1f} GiB is free on {device}: check the env's settings",
        )


def check_replay_memory(needed: int, capacity: int, device: torch.device) -> None:
    """A :class:`ConfigError` on ``buffer_size`` when the replay would not fit in memory (checked before
    allocating, instead of swapping or failing half-way; a checkpoint writes it without copying)."""
    free = available_memory(device)
    if free is not None and needed > 0.9 * free:
        raise ConfigError(
            "buffer_size",
            f"a replay of {capacity:,} transitions needs {needed / 2**30:.1f} GiB; "
            f"{free / 2**30:.1f} GiB is free on {device}: lower --buffer-size",
        )


def load_agent_state(agent: Any, state: dict[str, Any], where: Path) -> None:
    """``agent.load_state_dict(state)``; a checkpoint whose parts do not fit the run's ``config.json`` (another
    preset's settings over it, extra or missing keys, other shapes) is one :class:`ConfigError` naming it."""
    try:
        agent.load_state_dict(state)
    except (KeyError, RuntimeError, ValueError) as error:
        raise ConfigError(
            "checkpoint", f"{where} does not fit the run's config.json (another run's settings?): {reason(error, 160)}"
        ) from None


def restore(parts: RunParts, run_dir: Path) -> LoopState:
    """Load the last checkpoint of ``run_dir`` into the parts; the loop state to continue from."""
    saved = load_checkpoint(run_dir / "checkpoints", ("agent", "replay", "loop"), parts.device)
    parts.agent.load_state_dict(saved["agent"])  # a part that does not fit: _restore_checked says which settings changed
    if "replay" in saved and parts.replay is not None:
        parts.replay.load_state_dict(saved["replay"])
    loop_saved = dict(saved["loop"])
    parts.generator.set_state(loop_saved.pop("generator").cpu())
    return LoopState(**loop_saved)


def _restore_checked(parts: RunParts, run_dir: Path, saved: TrainConfig, config: TrainConfig) -> LoopState:
    """:func:`restore`, with a checkpoint that does not fit the settings given refused in one line
    (before the run's config.json is rewritten, so the run stays resumable as it was)."""
    try:
        return restore(parts, run_dir)
    except (RuntimeError, KeyError, ValueError, TypeError) as error:
        if isinstance(error, ConfigError):
            raise
        before, after = config_io.to_dict(saved), config_io.to_dict(config)
        changed = sorted(_changed_paths(before, after))
        what = f"the settings changed ({', '.join(changed)})" if changed else "its settings"
        raise ConfigError(
            "resume",
            f"the checkpoint in {run_dir} does not fit {what}: {reason(error)}; resume without changing them (the run is unchanged)",
        ) from None


def _changed_paths(before: Any, after: Any, prefix: str = "") -> list[str]:
    if isinstance(before, dict) and isinstance(after, dict):
        keys = sorted(set(before) | set(after))
        return [p for k in keys for p in _changed_paths(before.get(k), after.get(k), f"{prefix}{k}.")]
    return [] if before == after else [prefix.rstrip(".").rsplit(".", 1)[-1]]


def checkpointer(parts: RunParts, run_dir: Path) -> Callable[[LoopState], None]:
    """``(loop state) -> None`` writing agent, loop and (``save_replay``) replay parts, named by the
    run's progress (env steps; gradient updates for offline runs)."""
    axis = progress_axis(parts.config)

    def checkpoint(state: LoopState) -> None:
        saved: dict[str, Any] = {
            "agent": parts.agent.state_dict(),
            "loop": {**dataclasses.asdict(state), "generator": parts.generator.get_state()},
        }
        if parts.config.save_replay and parts.replay is not None:
            saved["replay"] = parts.replay.state_dict()
        save_checkpoint(run_dir / "checkpoints", saved, state.progress(axis))

    return checkpoint


# Loops by algorithm kind: (parts, bookkeeping) -> a loop with run(env_seed).
def _off_policy_loop(parts: RunParts, books: Bookkeeping) -> OffPolicyLoop:
    c = parts.config
    schedule = LoopSchedule(
        total_steps=c.total_steps,
        batch_size=c.batch_size,
        learning_starts=c.learning_starts,
        updates_per_step=c.updates_per_step,
        offline_updates=c.offline_updates,
        updates_per_call=c.updates_per_call,
    )
    return OffPolicyLoop(
        parts.env, parts.agent, parts.replay, parts.relabel, schedule, books, parts.generator, sample=parts.sampler
    )


def collector_env(config: TrainConfig, source: Any, num_envs: int, seed: int) -> BatchedEnv:
    """A collector's env copies (built in the collector's process, on CPU)."""
    import_env_module(config.env_module)
    return make_env(config, "cpu", num_envs=num_envs, seed=seed, source=source)


def role_agent(config: TrainConfig, env: Any = None, source: Any = None) -> Any:
    """The run's agent on CPU in a role's process: for ``env`` (a collector's), or for the run's spaces."""
    use_run_threads(config)
    if env is not None:
        return make_agent(config, env, torch.device("cpu"))
    import_env_module(config.env_module)
    family = env_family(config.env)
    request = dataclasses.replace(env_request(config, torch.device("cpu"), source), num_envs=1)
    built = family.make(config.env_settings, request)
    try:
        return make_agent(config, built, torch.device("cpu"))
    finally:
        built.close()


def _distributed_loop(parts: RunParts, books: Bookkeeping) -> DistributedLoop:
    """Collectors (and Bellman updaters) as Ray actors around this process, the trainer (``--distributed``)."""
    from taskrl.distributed.actors import RayPool

    c, cluster = parts.config, parts.config.cluster
    each = cluster.envs_each(c.num_envs)
    at = books.state.env_steps  # a resumed run's collectors start from new seeds
    collector_args = [
        (
            functools.partial(collector_env, c, parts.source, each),
            functools.partial(role_agent, c),
            c.seed + 10_007 * (i + 1) + at,
            c.threads,
        )
        for i in range(cluster.collectors)
    ]
    collectors = RayPool(Collector, collector_args, num_cpus=cluster.actor_cpus, max_restarts=cluster.max_restarts)
    parts.on_close.append(collectors.close)
    updaters = None
    if cluster.bellman_updaters:
        updater_args = [
            (functools.partial(role_agent, c, None, parts.source), c.seed + 20_011 * (j + 1) + at, c.threads)
            for j in range(cluster.bellman_updaters)
        ]
        updaters = RayPool(BellmanUpdater, updater_args, num_cpus=cluster.actor_cpus, max_restarts=cluster.max_restarts)
        parts.on_close.append(updaters.close)
    limiter = UpdateToDataLimiter(
        c.updates_per_step,
        c.learning_starts,
        c.offline_updates,
        lead_steps=CALLS_PER_COLLECTOR * cluster.collectors * each * cluster.collector_steps,
        enabled=cluster.limit_updates,
    )
    sample_batch = batch_sampler(parts.replay, parts.relabel, c.batch_size, parts.generator, parts.sampler)
    return DistributedLoop(
        parts.agent, parts.replay, sample_batch, collectors, updaters, cluster, c.total_steps, limiter, each, books
    )


def _on_policy_loop(parts: RunParts, books: Bookkeeping) -> OnPolicyLoop:
    return OnPolicyLoop(parts.env, parts.agent, parts.config.total_steps, books, parts.generator)


def _stored_data_loop(parts: RunParts, books: Bookkeeping) -> OfflineLoop:
    """``--offline``: an off-policy agent's updates on stored data (datasets, another run's replay) only."""
    c = parts.config
    sample_batch = batch_sampler(parts.replay, parts.relabel, c.batch_size, parts.generator, parts.sampler)
    return OfflineLoop(parts.agent, lambda size, generator: sample_batch(), c.total_steps, c.batch_size, books, parts.generator)


def _offline_loop(parts: RunParts, books: Bookkeeping) -> OfflineLoop:
    return OfflineLoop(
        parts.agent, parts.sampler.sample, parts.config.total_steps, parts.config.batch_size, books, parts.generator
    )


LOOPS: dict[str, Callable[[RunParts, Bookkeeping], Any]] = {
    "off_policy": _off_policy_loop,
    "on_policy": _on_policy_loop,
    "offline": _offline_loop,
}


RUN_INFO = "run.json"


def _run_title(run_dir: Path, preset: str | None, config: TrainConfig) -> str:
    """The run's name: its preset, recorded in ``run.json`` when it starts, so a resumed run keeps it."""
    info = run_dir / RUN_INFO
    if preset is not None:
        atomic_write_text(info, json.dumps({"preset": preset}) + "\n")
        return preset
    try:
        recorded = json.loads(info.read_text()).get("preset")
    except (OSError, ValueError, AttributeError):
        recorded = None
    return recorded if isinstance(recorded, str) and recorded else f"{config.env}-{config.algo}"


def default_run_dir(name: str) -> Path:
    return Path("runs") / f"{name}-{datetime.datetime.now():%Y%m%d-%H%M%S}"


# ---------------------------------------------------------------------- configuration of a call
def _env_source(overrides: dict[str, Any]) -> Any:
    """Read ``env=`` of :func:`train`: a family name stays a setting, a gymnasium id becomes
    ``env_id`` of the ``gym`` family, and a Python object (a factory, a TaskSet) is returned as
    the source its family builds envs from."""
    value = overrides.get("env")
    if value is None:  # env=None: not given
        overrides.pop("env", None)
        return None
    if isinstance(value, str) and value in ENV_FAMILIES:
        return None
    if isinstance(value, str):
        overrides.update(env="gym", env_id=value)
        return None
    overrides["env"] = family_for_source(value).name
    return value


def import_env_module(name: str) -> None:
    """Import the module that registers a user's gymnasium ids (``--env-module``)."""
    if not name:
        return
    try:
        importlib.import_module(name)
    except ImportError as error:
        raise ConfigError("env_module", f"cannot import {name!r}: {error}") from None


def _note(console: Console | None, notes: list[str]) -> None:
    out = console or Console(stderr=True)
    for line in notes:
        out.print(line if line.startswith("warning: ") else f"note: {line}", soft_wrap=True, markup=False)


def resolve_config(
    preset: str | None,
    resume: str | Path | None,
    overrides: dict[str, Any],
    notes: list[str] | None = None,
    base: TrainConfig | None = None,
) -> TrainConfig:
    """The settings a call would train with: the resumed run's, a given base config, or the preset's,
    with ``overrides`` applied (what changing env or algo kept or dropped goes to ``notes``)."""
    notes = [] if notes is None else notes
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / "config.json").exists():
            raise ConfigError("resume", f"{run_dir} is not a run directory (no config.json)")
        start = config_io.load(run_dir / "config.json")
    else:
        start = base if base is not None else preset_config(preset)
    config = with_overrides(start, overrides, notes)
    notes += [f"warning: {w}" for w in budget_warnings(config)]
    return config


def budget_warnings(config: TrainConfig) -> list[str]:
    """Budgets that make a run do less than its settings suggest (said before training, not refused)."""
    c, out = config, []
    if algorithm(c.algo).loop == "off_policy" and not c.offline:  # an offline run's total_steps are updates
        if c.learning_starts >= c.total_steps:
            out.append(
                f"learning_starts={c.learning_starts:,} >= total_steps={c.total_steps:,}: the run collects "
                f"data and makes no gradient update"
            )
        elif c.updates_per_step * (c.total_steps - c.learning_starts) < 1:
            out.append(
                f"updates_per_step={c.updates_per_step} over {c.total_steps - c.learning_starts:,} env steps "
                f"after learning_starts is less than one gradient update"
            )
    elif algorithm(c.algo).loop == "on_policy":
        rollout = getattr(c.algo_settings, "rollout_steps", 1) * c.num_envs
        if c.total_steps < rollout:
            out.append(f"total_steps={c.total_steps:,} is less than one rollout ({rollout:,} env steps): one rollout runs")
    return out


# ---------------------------------------------------------------------- training
def train(
    preset: str | None = "bitflip-her",
    *,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    progress: bool = False,
    tensorboard: bool = True,
    wandb: bool = False,
    console: Console | None = None,
    log_every: float = 0.0,
    base: TrainConfig | None = None,
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
        wandb: also log metrics and settings to Weights & Biases (the ``wandb`` extra; offline, into the run
            directory, without an account or network: ``WANDB_MODE`` decides when set).
        console: where the final table and notes go (default stderr).
        log_every: without a terminal, also print a progress line every this many seconds between
            evaluations (0: one line per evaluation only).
        base: a full configuration to start from instead of the preset's (``--config FILE``).
        **overrides: any setting by name (``n_bits=30``, ``lr=1e-3``; see ``taskrl train PRESET --help``).
            ``env`` may also be a gymnasium id (``env="my/Slider-v0"``), a zero-argument factory
            of a ``gymnasium.Env``, or a :class:`~taskrl.tasks.TaskSet`; a run on a Python object
            needs the same ``env=`` again to resume (and to :func:`load`).

    Returns:
        a :class:`Run` with the run directory, configuration, final metrics and trained agent.
    """
    overrides = dict(overrides)
    source = _env_source(overrides)
    notes: list[str] = []
    config = resolve_config(preset, resume, overrides, notes, base=base)
    if resume is not None:
        run_dir = Path(resume)
        saved = config_io.load(run_dir / "config.json")
    else:
        run_dir = check_new_run_dir(out if out is not None else default_run_dir(preset or "run"))
    if resume is None or "env_module" in overrides:  # a resumed run imports only what the caller names
        import_env_module(config.env_module)

    if wandb:  # before anything is written
        require_wandb()
    created = not run_dir.exists()
    lock = RunLock(run_dir, "resume" if resume is not None else "out")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        lock.__enter__()
        family = env_family(config.env)
        if source is not None and resume is None and family.persist is not None:  # record the object in the run
            config = with_overrides(config, family.persist(source, run_dir))
        validate(config)
        parts = build(config, source)
        # A new run checkpoints after its first step (a kill before checkpoint_interval still resumes);
        # a resumed run loads its checkpoint before anything of it is rewritten.
        try:
            if resume is None and config.offline_data:
                preload_replay(parts, config.offline_data)
            if resume is None and dataset_steps(config, parts.env):
                preload_datasets(parts)
            state = (
                LoopState(next_checkpoint=0, next_eval=_first_evaluation(config))
                if resume is None
                else _restore_checked(parts, run_dir, saved, config)
            )
        except BaseException:
            parts.close()
            raise
    except BaseException:
        lock.__exit__()
        if created:  # nothing of this call stays behind
            shutil.rmtree(run_dir, ignore_errors=True)
        raise
    try:
        axis = progress_axis(config)
        if resume is not None and state.progress(axis) >= config.total_steps:
            notes.append(
                f"the run is finished: {state.progress(axis):,} of total_steps {config.total_steps:,} {axis.replace('_', ' ')}; "
                f"to train on, extend it: taskrl train --resume {run_dir} --total-steps {2 * config.total_steps}"
            )
        _note(console, notes)
        config_io.save(config, run_dir / "config.json")
        at = state.progress(axis)
        tracking = {"name": run_dir.name, "config": config_io.to_dict(config)} if wandb else None
        logger = RunLogger(run_dir, tensorboard=tensorboard, resume_from_step=at if resume else None, axis=axis, wandb=tracking)
        rows: list[dict[str, Any]] = []
        title = _run_title(run_dir, preset if resume is None else None, config)
        evaluator, last_eval = make_evaluator(config, parts.eval_env, parts.agent, config.seed + EVAL_SEED_OFFSET)
        stop = StopRequest(config.max_hours)
        with ConsoleReporter(title, config.total_steps, at, enabled=progress, log_every=log_every, axis=axis) as reporter:

            def on_log(row: dict[str, Any]) -> None:
                rows.append(row)
                logger.log(row)
                reporter.update(row)

            books = Bookkeeping(
                state,
                evaluator,
                on_log,
                checkpointer(parts, run_dir),
                config.total_steps,
                config.eval_interval,
                config.checkpoint_interval,
                config.stop_at_success,
                parts.device,
                stop,
                checkpoint_seconds=60.0 * config.checkpoint_minutes,
                axis=axis,
            )
            books.heartbeat = reporter.heartbeat
            books.on_train_log, books.train_log_interval = logger.log_training, config.tensorboard_interval
            if config.cluster.distributed:
                make_loop = _distributed_loop
            else:
                make_loop = _stored_data_loop if config.offline else LOOPS[algorithm(config.algo).loop]
            loop = make_loop(parts, books)
            if parts.replay is not None:  # what the replay holds and has dropped
                books.row_metrics.append(lambda elapsed: parts.replay.metrics())
            if parts.sharing is not None:  # how much of each task's rows came from which task
                sharing, names = parts.sharing, list(parts.env.task_set.names)
                books.row_metrics.append(lambda elapsed: sharing.metrics(names))
            try:
                with stop.on_signals():
                    state = loop.run(env_seed=config.seed + state.env_steps)
            finally:
                logger.close()
                parts.close()
    finally:
        lock.__exit__()

    final = report(config, run_dir, title, rows, state, last_eval, logger.path, progress, console, stop)
    return Run(run_dir=run_dir, config=config, metrics=final, agent=parts.agent, stopped_by=stop.stopped_by, notes=notes)


def report(
    config: TrainConfig,
    run_dir: Path,
    title: str,
    rows: list[dict[str, Any]],
    state: LoopState,
    last_eval: dict[str, Any],
    metrics_csv: Path,
    progress: bool,
    console: Console | None,
    stop: StopRequest,
) -> dict[str, Any]:
    """The learning curve, the per-task result of multi-task runs, the final table; returns the last row."""
    out = console or Console(stderr=True)
    curve = plot_learning_curve(metrics_csv, run_dir / "learning_curve.png", title=f"{title} ({run_dir.name})")
    if last_eval:  # multi-task: the per-task table of the last evaluation, printed and saved
        at = {"env_steps": state.env_steps, "updates": state.updates}
        (run_dir / "per_task_success.json").write_text(json.dumps({**at, **last_eval}, indent=2) + "\n")
        if progress:
            out.print(per_task_table(last_eval, f"per-task success at {_progress_text(config, state)}"))
    final = (
        rows[-1]
        if rows
        else {
            "env_steps": state.env_steps,
            "updates": state.updates,
            "wall_seconds": state.wall_seconds,
            "success_rate": state.last_success,
        }
    )
    if progress:
        out.print(final_table({"eval_return": float("nan"), **final}, run_dir, curve))
    if stop.stopped_by:
        out.print(
            f"stopped early ({stop.stopped_by}) at {_progress_text(config, state)}, checkpoint saved; "
            f"continue with: taskrl train --resume {run_dir}",
            soft_wrap=True,
            markup=False,
        )
    return final


def _progress_text(config: TrainConfig, state: LoopState) -> str:
    if progress_axis(config) == "updates":
        return f"{state.updates:,} gradient updates"
    return f"{state.env_steps:,} env steps"


# ---------------------------------------------------------------------- loading
def _saved_config(run_dir: Path, env: Any, env_module: str | None) -> tuple[TrainConfig, Any]:
    """A run directory's config and the env source a caller passed for it."""
    if not (run_dir / "config.json").exists():
        raise ConfigError("run_dir", f"{run_dir} is not a run directory (no config.json)")
    config = config_io.load(run_dir / "config.json")
    if env_module:
        import_env_module(env_module)
    if env is not None and (not isinstance(env, str)):
        return config, env
    return config, None


def load(
    run_dir: str | Path, device: str = "cpu", env: Any = None, env_module: str | None = None, checkpoint: int | None = None
) -> Any:
    """The trained agent of a run directory; ``agent.act(obs)`` takes the environment's observations.

    Only safetensors and JSON are read: loading never executes code, and never imports a module
    the run directory names (pass ``env_module`` to register a gymnasium id of yours first).

    Args:
        run_dir: a directory written by :func:`train`.
        device: where the networks go.
        env: the Python factory or TaskSet the run was trained on, if it was trained on one.
        env_module: a module to import first (one that registers the run's gymnasium id).
        checkpoint: the env step of the checkpoint to load (default the latest); the loaded agent's
            ``loaded_step`` says which.
    """
    return load_run(run_dir, device, env, env_module, checkpoint)[0]


@dataclasses.dataclass(frozen=True)
class RunSpaces:
    """The spaces (and task set) of a run's env: what its agent is built from."""

    single_observation_space: gym.spaces.Space
    single_action_space: gym.spaces.Space
    task_set: Any = None

    def close(self) -> None:
        """Nothing to release."""


def load_run(
    run_dir: str | Path, device: str = "cpu", env: Any = None, env_module: str | None = None, checkpoint: int | None = None
) -> tuple[Any, TrainConfig, RunSpaces]:
    """``(agent, config, spaces)`` of a run directory (arguments as :func:`load`); the env is built
    once, or not at all where its family can give the spaces without it (Meta-World)."""
    run_dir = Path(run_dir)
    config, source = _saved_config(run_dir, env, env_module)
    dev = resolve_device(device)
    family = env_family(config.env)
    request = dataclasses.replace(env_request(config, dev, source, evaluation=True), eval_episodes=1)
    if family.spec is not None and source is None:  # spaces and task set only: building Meta-World takes seconds
        built = family.spec(config.env_settings, request)
    else:
        built = family.make(config.env_settings, request)
    try:
        spaces = RunSpaces(built.single_observation_space, built.single_action_space, getattr(built, "task_set", None))
        agent = make_agent(config, built, dev)
    finally:
        built.close()
    folder = checkpoint_at(run_dir / "checkpoints", checkpoint)
    load_agent_state(agent, read_checkpoint(folder, ("agent",), dev)["agent"], folder / "agent.safetensors")
    agent.loaded_step = checkpoint_step(folder)
    return agent, config, spaces


def use_run_threads(config: TrainConfig) -> None:
    """Evaluate with the torch threads the run trained with (``--threads``; 0 keeps torch's default):
    more threads than free cores makes small policies many times slower."""
    if config.threads:
        torch.set_num_threads(config.threads)


def per_task_intervals(tasks: dict[str, dict[str, Any]]) -> tuple[dict[str, dict[str, Any]], list[float]]:
    """Each task's row with its 95% Wilson interval, and the interval of all their episodes together."""
    rows = {
        name: {**t, "success_ci95": wilson_interval(t["success_rate"] * t["episodes"], t["episodes"])}
        for name, t in tasks.items()
    }
    total = sum(t["episodes"] for t in tasks.values())
    return rows, wilson_interval(sum(t["success_rate"] * t["episodes"] for t in tasks.values()), total)


def wilson_interval(successes: float, n: int, z: float = 1.96) -> list[float]:
    """The 95% Wilson score interval of a success rate (sound at 0 and 1, where a normal one is not)."""
    if n <= 0:
        return [0.0, 1.0]
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [max(0.0, centre - half), min(1.0, centre + half)]


def evaluate_run(
    run_dir: str | Path,
    episodes: int = 100,
    seed: int | None = None,
    device: str = "cpu",
    env: Any = None,
    env_module: str | None = None,
    checkpoint: int | None = None,
    stochastic: bool = False,
    video: int = 0,
) -> dict[str, Any]:
    """Re-evaluate a saved agent on ``episodes`` fresh episodes (per task on multi-task envs).

    Args:
        run_dir: a run directory.
        episodes: episodes (per task on multi-task envs).
        seed: evaluation seed (default the run's own evaluation seed: the same episodes it was scored on).
        device: where the networks go.
        env: as for :func:`load`.
        env_module: as for :func:`load`.
        checkpoint: the env step of the checkpoint to evaluate (default the latest).
        stochastic: act with the algorithm's exploration instead of greedily.
        video: also record this many episodes to ``run_dir/videos/`` (MP4).

    Returns:
        ``success_rate`` with its 95% Wilson interval ``success_ci95``, ``eval_return`` with
        ``eval_return_ci95`` (normal, over episodes; single-task envs), ``eval_length``, ``episodes``,
        ``checkpoint_step``, on multi-task envs a ``success/<task>`` per task and ``tasks`` (each with
        its own interval), and ``videos`` (paths) when asked.
    """
    run_dir = Path(run_dir)
    if video:  # MuJoCo renders off-screen through EGL without a display; read when MuJoCo is first imported
        os.environ.setdefault("MUJOCO_GL", "egl")
    config, source = _saved_config(run_dir, env, env_module)
    config = dataclasses.replace(config, eval_episodes=episodes)
    use_run_threads(config)
    if video:  # say so before evaluating, not after
        from taskrl.video import check_can_record

        check_can_record(config)
    try:  # before loading anything
        validate(config)
    except ConfigError as error:  # the only setting this call changes is the episode count
        raise ConfigError("episodes" if error.field == "eval_episodes" else error.field, error.message) from None
    agent = load(run_dir, device, env=source, env_module=None, checkpoint=checkpoint)
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else seed
    eval_env = make_env(config, agent.device, seed=seed, evaluation=True, source=source)
    try:
        run, last = make_evaluator(config, eval_env, agent, seed, stochastic=stochastic, details=True)
        result = {**run(), "episodes": episodes, "checkpoint_step": agent.loaded_step}
        result["checkpoint_unit"] = "gradient updates" if progress_axis(config) == "updates" else "env steps"
    finally:
        eval_env.close()
    if last:  # multi-task: an interval for every task and for the mean's share of episodes
        result["tasks"], result["success_ci95"] = per_task_intervals(last["tasks"])
    else:
        result["success_ci95"] = wilson_interval(result.pop("successes"), episodes)
        returns = torch.tensor(result.pop("returns"), dtype=torch.float64)
        half = 1.96 * returns.std().item() / math.sqrt(len(returns)) if len(returns) > 1 else float("nan")
        result["eval_return_ci95"] = [result["eval_return"] - half, result["eval_return"] + half]
    if video:
        from taskrl.video import record_episodes

        result["videos"] = [str(p) for p in record_episodes(agent, config, run_dir / "videos", video, seed, stochastic)]
    return result
