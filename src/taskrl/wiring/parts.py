"""A run's parts: its envs, agent, evaluator and relabeller, each built from a validated config."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import torch

from taskrl.agents.registry import algorithm
from taskrl.agents.spec import AgentInputs, AlgorithmSpec
from taskrl.conditioning.networks import make_conditioning
from taskrl.config import TrainConfig
from taskrl.encoders import PICTURE_KEYS
from taskrl.envs.base import BatchedEnv
from taskrl.envs.registry import env_family
from taskrl.envs.spec import EnvFamily, EnvRequest, env_kind
from taskrl.errors import ConfigError, require
from taskrl.fit import check_fit
from taskrl.replay import EpisodeReplay, HindsightRelabeler
from taskrl.setting_values import check_device
from taskrl.sharing import TaskSharing
from taskrl.training.evaluation import ActingPolicy, evaluate
from taskrl.training.per_task import evaluate_per_task
from taskrl.types import PicturePose

__all__ = ["RunParts", "make_agent", "make_env", "make_evaluator", "make_relabeler", "resolve_device"]

#: Observation keys the networks read, where the env has them (the task index is read separately).
# the pictures (kept as pictures beside the vector of the others). A goal given as a picture replaces the state goal as input
# (the state goal stays in the observation for rewards and relabelling).
AGENT_INPUT_KEYS = ("observation", "desired_goal", "image", "goal_image")


EVAL_SEED_OFFSET = 1_000_003


def resolve_device(name: str) -> torch.device:
    """``cpu``, ``cuda``, ``cuda:N`` or ``auto``; a `ConfigError` for any other name or absent CUDA."""
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
        eval_episodes=config.evaluation.eval_episodes,
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
    family: EnvFamily | None = None,
) -> BatchedEnv:
    """The run's training env (or, with ``evaluation``, its evaluation env), built by its env family.

    Args:
        config: a validated configuration.
        device: where the env's tensors live.
        num_envs: training copies (default ``config.num_envs``).
        seed: the env's seed (default the run's, or its evaluation seed).
        evaluation: the evaluation env (one copy per episode, or fixed tasks per copy).
        source: the Python object (factory, TaskSet) the run's family builds from, if any.
        family: the run's env family, where a plan resolved it (default: looked up by ``config.env``, as a
            process that reads a saved config does).
    """
    request = env_request(config, torch.device(device), source, evaluation, seed)
    if num_envs is not None:
        request = dataclasses.replace(request, num_envs=num_envs)
    return (family or env_family(config.env)).make(config.env_settings, request)


def make_agent(config: TrainConfig, env: Any, device: torch.device, spec: AlgorithmSpec | None = None) -> Any:
    """The agent of ``config.algo`` for ``env``'s spaces (an env, or an object with its spaces); ``spec``: the
    algorithm where a plan resolved it (default: looked up by ``config.algo``).

    The env is checked against the algorithm with the same rules as before building
    ([`taskrl.fit.check_fit`][taskrl.fit.check_fit]), now with the env's real kind and action space.
    """
    spec = spec or algorithm(config.algo)
    check_fit(
        config, env_kind(env), action_kind(env.single_action_space), "image" in env.single_observation_space.spaces, spec=spec
    )
    if action_kind(env.single_action_space) is None:
        raise ConfigError("env", f"actions must be Box or Discrete; {config.env!r} has {env.single_action_space}")
    space = env.single_observation_space
    keys = tuple(k for k in AGENT_INPUT_KEYS if k in space.spaces)
    if "goal_image" in keys:
        keys = tuple(k for k in keys if k != "desired_goal")
    if "observation" not in keys and "image" not in keys:
        raise ConfigError(
            "env",
            f"observations have keys {list(space.spaces)}; the networks read 'observation' or 'image' "
            f"(with 'desired_goal' on goal envs and 'task' on multi-task envs)",
        )
    input_dim = sum(int(torch.tensor(space[k].shape).prod()) for k in keys)
    task_set = getattr(env, "task_set", None)
    conditioning = None
    if env_kind(env) == "multitask" and task_set is not None and len(task_set) > 1:  # one task needs no context
        conditioning = make_conditioning(config.conditioning, len(task_set), task_set.descriptions)
    image_shape = tuple(space["image"].shape) if "image" in keys else None
    if image_shape is not None and "goal_image" in keys:  # two pictures, encoded together
        image_shape = (2, *image_shape)
    check_network_memory(config, input_dim, device)
    shift = getattr(config.env_settings, "shift", -1)  # the camera's (CameraSettings); -1: the algorithm's own
    coordinates: tuple = ()
    if getattr(config.env_settings, "shift_coordinates", False):
        coordinates = tuple(getattr(env, "picture_coordinates", ()))
        require(
            bool(coordinates),
            "shift_coordinates",
            f"{config.env!r} declares no position in the picture's frame in its state (picture_coordinates) to move",
        )
    inputs = AgentInputs(
        keys,
        input_dim,
        env.single_action_space,
        image_shape,
        shift if shift >= 0 else None,
        coordinates,
        pose_in_vector(env, keys),
    )
    return spec.build(inputs, config.algo_settings, device, conditioning)


def pose_in_vector(env: BatchedEnv, keys: tuple[str, ...]) -> PicturePose | None:
    """The gripper's pose the env declares (``picture_pose``), its columns counted in the agent's state vector (the
    vector keys of ``keys`` concatenated in order); None where the env declares none or the agent does not read it."""
    pose = getattr(env, "picture_pose", None)
    vector_keys = [k for k in keys if k not in PICTURE_KEYS]
    if pose is None or pose.key not in vector_keys:
        return None
    space = env.single_observation_space
    offset = sum(int(math.prod(space[k].shape)) for k in vector_keys[: vector_keys.index(pose.key)])
    return pose.in_vector(offset)


def make_evaluator(
    config: TrainConfig,
    eval_env: BatchedEnv,
    agent: Any,
    seed: int,
    stochastic: bool = False,
    details: bool = False,
    family: EnvFamily | None = None,
):
    """``() -> metrics`` for the loop, and a holder of the last full result (per-task for multi-task envs).

    Single-task envs: success at the step an episode ends, one episode per evaluation copy.
    Multi-task envs: `evaluate_per_task` with ``eval_episodes`` per task and the family's
    success criterion (any step on Meta-World, its protocol; the final step on the native
    multi-task PointReach, where touring regions must not count). ``success_rate`` is the mean
    over tasks and every task adds a ``success/<name>`` column.
    """
    last: dict[str, Any] = {}
    multitask = env_kind(eval_env) == "multitask"
    # once, not at every evaluation (a task set's criterion reads its task file)
    criterion = (family or env_family(config.env)).success_criterion(config.env_settings) if multitask else None

    policy = ActingPolicy(agent, explore=stochastic)  # greedy unless asked to explore

    def run() -> dict[str, float]:
        if not multitask:
            return evaluate(policy, eval_env, seed, details=details)
        result = evaluate_per_task(policy, eval_env, config.evaluation.eval_episodes, seed, success=criterion)
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
    if config.replay.her == "none":
        return None
    return HindsightRelabeler(
        env.compute_reward,
        config.replay.her,
        config.replay.her_k,
        terminated_fn=getattr(env, "compute_terminated", None),
        goal_picture_fn=getattr(env, "goal_picture", None),
    )


@dataclasses.dataclass
class RunParts:
    """Everything a run is made of, built from its config (`build`)."""

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
    """A `ConfigError` before allocating networks that cannot fit (a hand-edited ``config.json`` whose env
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
    """A `ConfigError` on ``buffer_size`` when the replay would not fit in memory (checked before
    allocating, instead of swapping or failing half-way; a checkpoint writes it without copying)."""
    free = available_memory(device)
    if free is not None and needed > 0.9 * free:
        raise ConfigError(
            "buffer_size",
            f"a replay of {capacity:,} transitions needs {needed / 2**30:.1f} GiB; "
            f"{free / 2**30:.1f} GiB is free on {device}: lower --buffer-size",
        )


def use_run_threads(config: TrainConfig) -> None:
    """Evaluate with the torch threads the run trained with (``--threads``; 0 keeps torch's default):
    more threads than free cores makes small policies many times slower."""
    if config.threads:
        torch.set_num_threads(config.threads)
