"""What the registry knows about an algorithm: `AlgorithmSpec` (each agent's file declares its ``SPEC``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Literal

import gymnasium as gym
import torch

__all__ = ["AgentInputs", "AlgorithmSpec", "LoopKind"]

LoopKind = Literal["off_policy", "on_policy", "offline"]


@dataclasses.dataclass(frozen=True)
class AgentInputs:
    """What an agent is built for: the observation keys its networks read, the numbers one observation holds under
    them, and the action space; on envs with a camera, the pictures' shape ``(H, W, C)`` (``(2, H, W, C)`` with a goal
    picture). Pictures reach the networks as stored, beside the vector of the other keys
    ([`PictureState`][taskrl.types.PictureState]). ``picture_shift``: the camera's random shift of the pictures the
    agent trains on, in pixels (`taskrl.envs.camera.CameraSettings.shift`); None: the algorithm's own.
    ``picture_coordinates``: the vector entries the shift moves with the picture (`taskrl.encoders.PictureCoordinate`;
    empty unless the camera's ``shift_coordinates`` is on). ``picture_pose``: where the gripper's pose in the picture
    is in the state vector, for envs that declare one (`taskrl.types.PicturePose`, columns counted in the vector),
    else None."""

    keys: tuple[str, ...]
    dim: int
    action_space: gym.spaces.Space
    image_shape: tuple[int, ...] | None = None
    picture_shift: int | None = None
    picture_coordinates: tuple[Any, ...] = ()
    picture_pose: Any = None


@dataclasses.dataclass(frozen=True)
class AlgorithmSpec:
    """One algorithm, as runs and the command line see it.

    Attributes:
        name: the value of ``--algo`` and the name of its settings section.
        description: one line for ``--help``.
        config: its settings dataclass (a ``validate()`` method raises ``ConfigError``).
        build: ``build(inputs, config, device, conditioning) -> agent``; ``conditioning`` is a
            ``TaskConditioning`` on multi-task envs, else None.
        loop: ``off_policy`` (replay, relabelling), ``on_policy`` (rollouts) or ``offline`` (a dataset;
            its settings name it in ``dataset``; ``total_steps`` counts gradient updates).
        actions: the action spaces it supports: ``discrete`` (``Discrete``), ``box`` (``Box``).
        multitask: whether it can condition its networks on a task (multi-task envs).
        bellman_updaters: whether its agent splits an update into ``bellman_target(batch)`` and
            ``regress(batch, target)`` with ``bellman_parts`` (the weights targets read), so Bellman
            updaters can compute targets apart from the trainer (QT-Opt).
        compiles: whether its update runs as one compiled graph (``--compile``; its agent
            implements ``learn``, see `taskrl.agents.compiled`).
        q_values: whether its agent has ``q_value(obs, action) -> [B]``, the Q of each row under the row's task
            (what a sharing strategy that ranks rows by Q reads).
        images: whether its networks encode an ``image`` observation (a conv encoder); others refuse envs with a camera.
        parent: the registered algorithm this one is a variant of: switching ``--algo`` between the two (or two
            variants of one parent) keeps every setting their sections share by name (exploration included),
            not only the settings every algorithm shares.
    """

    name: str
    description: str
    config: type
    build: Callable[[AgentInputs, Any, torch.device, Any], Any]
    loop: LoopKind
    actions: tuple[str, ...]
    multitask: bool = False
    bellman_updaters: bool = False
    compiles: bool = False
    q_values: bool = False
    parent: str | None = None
    images: bool = False
