"""Pixels from any gymnasium env that renders: its ``render()`` frame as an ``image`` observation.

``--observation pixels`` (or ``pixels+state``) on the Fetch families and the ``gym`` family wraps every copy
in `PixelObservation`: the env is made with ``render_mode="rgb_array"`` (at ``--image-size`` where its
renderer takes ``width`` / ``height``, as MuJoCo's do; otherwise the frame is resized), and the observation
becomes a dict with

- ``image``: ``[size, size, 3]`` uint8, channels last (gymnasium's image convention);
- ``observation``: the env's state vector, with ``pixels+state`` only;
- every other key of a dict observation as it was: ``achieved_goal`` / ``desired_goal`` of goal envs, so
  hindsight relabelling and ``compute_reward`` stay exact while the policy sees the scene as a picture, and a
  multi-task env's ``task`` index.

MuJoCo renders off-screen through EGL (``MUJOCO_GL=egl``, set here when unset). On a 2-core CPU a 64x64
FetchReach frame costs about 20 ms: pixels from MuJoCo are for short runs and tests here, and for GPU machines.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F

from taskrl.errors import ConfigError, one_of

__all__ = ["OBSERVATIONS", "PixelObservation", "check_pixel_settings", "pixel_factory"]

OBSERVATIONS = ("state", "pixels", "pixels+state")


def check_pixel_settings(settings: Any) -> None:
    """A family's ``observation`` setting (its ``image_size`` is its `CameraSettings`'); a ConfigError names it."""
    one_of(settings.observation, OBSERVATIONS, "observation", "observation")


class PixelObservation(gym.ObservationWrapper):
    """An env's rendered frame as the ``image`` observation (module docstring).

    Args:
        env: an env made with ``render_mode="rgb_array"``.
        size: the picture's side in pixels (frames of another size are resized by area averaging).
        keep_state: also return the env's state vector as ``observation``.
    """

    def __init__(self, env: gym.Env, size: int = 64, keep_state: bool = False) -> None:
        super().__init__(env)
        if env.render_mode != "rgb_array":
            name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
            raise ConfigError(
                "observation",
                f"pixels need an env that renders rgb_array frames; {name} has render_mode {env.render_mode!r} "
                "(allowed: state for this env)",
            )
        self.size, self.keep_state = int(size), bool(keep_state)
        space = env.observation_space
        entries = dict(space.spaces) if isinstance(space, gym.spaces.Dict) else {"observation": space}
        kept = {k: v for k, v in entries.items() if k != "observation" or keep_state}
        self.observation_space = gym.spaces.Dict({**kept, "image": gym.spaces.Box(0, 255, (self.size, self.size, 3), np.uint8)})
        self._dict = isinstance(space, gym.spaces.Dict)

    def observation(self, observation: Any) -> dict[str, Any]:
        entries = observation if self._dict else {"observation": observation}
        out = {k: entries[k] for k in self.observation_space.spaces if k != "image"}
        out["image"] = self.frame()
        return out

    def frame(self) -> np.ndarray:
        """The env's current frame at ``size x size`` (uint8, channels last)."""
        frame = np.asarray(self.env.render())
        if frame.shape[:2] != (self.size, self.size):
            resized = F.interpolate(
                torch.from_numpy(frame.copy()).permute(2, 0, 1)[None].float(), (self.size, self.size), mode="area"
            )
            frame = resized[0].permute(1, 2, 0).round().clamp(0, 255).to(torch.uint8).numpy()
        return np.ascontiguousarray(frame[..., :3], dtype=np.uint8)


def _render_env(make: Callable[..., gym.Env], size: int) -> gym.Env:
    """``make(render_mode="rgb_array", width=size, height=size)``; without the size, or without arguments (a
    factory that sets its own render mode), where the env refuses them."""
    os.environ.setdefault("MUJOCO_GL", "egl")  # off-screen MuJoCo without a display
    for kwargs in ({"render_mode": "rgb_array", "width": size, "height": size}, {"render_mode": "rgb_array"}, {}):
        try:
            return make(**kwargs)
        except TypeError:
            continue
    raise ValueError("the env factory takes neither render_mode nor no arguments")


class pixel_factory:  # noqa: N801 (used like a function; a class so async workers can pickle it)
    """A zero-argument factory of one pixel-observation copy: of a gymnasium id, or of a user's factory that
    takes ``render_mode`` (and ``width`` / ``height`` where it can).

    Args:
        source: a registered gymnasium id or a factory ``(**render_kwargs) -> gym.Env``.
        mode: ``pixels`` or ``pixels+state``.
        size: the picture's side in pixels.
    """

    def __init__(self, source: str | Callable[..., gym.Env], mode: str, size: int) -> None:
        if mode not in OBSERVATIONS[1:]:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS[1:])} for pixels (got {mode!r})")
        self.source, self.mode, self.size = source, mode, int(size)
        self.__name__ = f"pixels:{source if isinstance(source, str) else getattr(source, '__name__', 'env')}"

    def __call__(self) -> gym.Env:
        if isinstance(self.source, str):
            from taskrl.envs.gymnasium_adapter import _ensure_registered

            _ensure_registered(self.source)
            env = _render_env(lambda **kw: gym.make(self.source, **kw), self.size)
        else:
            env = _render_env(self.source, self.size)
        return PixelObservation(env, self.size, keep_state=self.mode == "pixels+state")
