"""Policy export: what acting needs, without replay, optimisers or target networks.

``taskrl export RUN_DIR --out policy/`` writes ``policy/policy.safetensors`` (the acting networks and
the input normaliser) and ``policy/policy.json`` (the settings, the observation and action spaces,
the task set), and ``taskrl.load_policy("policy/")`` gives a `Policy` whose ``predict(obs)``
takes one observation or a batch, numpy in, numpy out. Loading reads safetensors and JSON only.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from safetensors.torch import load_file, save_file

from taskrl.errors import ConfigError, reason
from taskrl.rundir import atomic_write_text
from taskrl.tasks import TaskSet
from taskrl.types import PictureCoordinate, PicturePose

__all__ = ["FORMAT", "Policy", "export_policy", "load_policy", "space_from_json", "space_to_json"]

FORMAT = "taskrl-policy/1"


def space_to_json(space: gym.spaces.Space) -> dict[str, Any]:
    """A JSON description of a ``Box``, ``Discrete`` or ``Dict`` space."""
    if isinstance(space, gym.spaces.Dict):
        return {"type": "Dict", "spaces": {k: space_to_json(s) for k, s in space.spaces.items()}}
    if isinstance(space, gym.spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if isinstance(space, gym.spaces.MultiBinary):
        return {"type": "MultiBinary", "n": np.asarray(space.n).tolist()}
    if isinstance(space, gym.spaces.MultiDiscrete):
        return {"type": "MultiDiscrete", "nvec": space.nvec.tolist()}
    if isinstance(space, gym.spaces.Box):
        return {
            "type": "Box",
            "low": space.low.tolist(),
            "high": space.high.tolist(),
            "shape": list(space.shape),
            "dtype": str(space.dtype),
        }
    raise ValueError(f"cannot export a {type(space).__name__} space")


def space_from_json(data: dict[str, Any]) -> gym.spaces.Space:
    """The space `space_to_json` described."""
    kind = data.get("type")
    if kind == "Dict":
        return gym.spaces.Dict({k: space_from_json(v) for k, v in data["spaces"].items()})
    if kind == "Discrete":
        return gym.spaces.Discrete(int(data["n"]), start=int(data.get("start", 0)))
    if kind == "MultiBinary":
        return gym.spaces.MultiBinary(data["n"])
    if kind == "MultiDiscrete":
        return gym.spaces.MultiDiscrete(data["nvec"])
    if kind == "Box":
        dtype = np.dtype(data["dtype"])
        return gym.spaces.Box(
            np.asarray(data["low"], dtype=dtype), np.asarray(data["high"], dtype=dtype), shape=tuple(data["shape"]), dtype=dtype
        )
    raise ValueError(f"unknown space type {kind!r}")


def export_policy(
    run_dir: str | Path, out: str | Path, device: str = "cpu", env: Any = None, env_module: str | None = None
) -> Path:
    """Write the acting part of a run's latest checkpoint to ``out`` (a new or empty directory)."""
    from taskrl import config as config_io
    from taskrl.checkpoint import flatten_state
    from taskrl.loading import load_run

    run_dir, out = Path(run_dir), Path(out)
    try:
        occupied = out.exists() and (not out.is_dir() or any(out.iterdir()))
    except OSError as error:  # a name too long, a folder it may not read
        raise ConfigError("out", f"cannot use {out}: {error.strerror}") from None
    if occupied:
        raise ConfigError("out", f"{out} exists and is not an empty directory")
    agent, config, spaces = load_run(run_dir, device, env=env, env_module=env_module)
    meta = {
        "format": FORMAT,
        "config": config_io.to_dict(config),
        "observation_space": space_to_json(spaces.single_observation_space),
        "action_space": space_to_json(spaces.single_action_space),
        "task_set": [{"name": t.name, "description": t.description} for t in spaces.task_set] if spaces.task_set else None,
        # what the env declares about its pictures, which the agent is built from (a glimpse's pose)
        "picture_coordinates": [dataclasses.asdict(c) for c in spaces.picture_coordinates],
        "picture_pose": dataclasses.asdict(spaces.picture_pose) if spaces.picture_pose is not None else None,
    }
    tensors, skeleton = flatten_state(agent.state_dict(parts=agent.acting))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # a name too long, no permission, a file on the way
        raise ConfigError("out", f"cannot create {out}: {error.strerror}") from None
    save_file(tensors, str(out / "policy.safetensors"))
    atomic_write_text(out / "policy.json", json.dumps({**meta, "state": skeleton}, indent=2) + "\n")
    return out


class Policy:
    """An exported policy: ``predict(obs)`` on one observation or a batch, numpy in, numpy out.

    Attributes:
        agent: the agent rebuilt with its acting networks (``agent.act`` takes tensors too).
        config: the run's settings.
        observation_space, action_space: the spaces of the env it was trained on.
    """

    def __init__(self, agent: Any, config: Any, observation_space: gym.spaces.Space, action_space: gym.spaces.Space) -> None:
        self.agent, self.config = agent, config
        self.observation_space, self.action_space = observation_space, action_space

    def predict(self, obs: Any, deterministic: bool = True) -> Any:
        """Actions for ``obs`` (the greedy policy; ``deterministic=False`` samples, as collection does)."""
        if isinstance(obs, dict):
            obs = {k: np.asarray(v.cpu() if isinstance(v, torch.Tensor) else v) for k, v in obs.items()}
        else:
            obs = np.asarray(obs.cpu() if isinstance(obs, torch.Tensor) else obs)
        action = self.agent.act(obs, explore=not deterministic)
        return action if isinstance(action, (int, np.ndarray)) else np.asarray(action)


def load_policy(path: str | Path, device: str = "cpu") -> Policy:
    """Read an exported policy (``policy.json`` + ``policy.safetensors``); never executes code."""
    from taskrl.checkpoint import unflatten_state
    from taskrl.config import from_dict
    from taskrl.loading import RunSpaces
    from taskrl.wiring.parts import make_agent, resolve_device

    path = Path(path)
    try:
        meta = json.loads((path / "policy.json").read_text())
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ValueError(f"not a {FORMAT} file")
        tensors = load_file(str(path / "policy.safetensors"), device=str(resolve_device(device)))
        observation_space, action_space = space_from_json(meta["observation_space"]), space_from_json(meta["action_space"])
        coordinates = tuple(PictureCoordinate(**c) for c in meta.get("picture_coordinates", []))
        pose = PicturePose(**meta["picture_pose"]) if meta.get("picture_pose") else None
    except ConfigError:
        raise
    except Exception as error:  # missing, damaged or foreign files: one line
        raise ConfigError("policy", f"{path} is not a taskrl policy ({reason(error)})") from None
    config = from_dict(meta["config"])
    tasks = meta.get("task_set")
    spaces = RunSpaces(
        observation_space,
        action_space,
        TaskSet.from_pairs((t["name"], t["description"]) for t in tasks) if tasks else None,
        coordinates,
        pose,
    )
    # acting needs no replay: relabelling and batch sampling are training settings, off here
    agent = make_agent(
        dataclasses.replace(config, replay=dataclasses.replace(config.replay, her="none", sampling="uniform")),
        spaces,
        resolve_device(device),
    )
    agent.load_parts(unflatten_state(tensors, meta["state"]))
    return Policy(agent, config, observation_space, action_space)
