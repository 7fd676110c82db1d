"""The Fetch robotics tasks (gymnasium-robotics ``*-v4``, MuJoCo) as env families.

They need the ``robotics`` extra. Every copy is a gymnasium env behind
[`GymnasiumGoalEnv`][taskrl.envs.gymnasium_adapter.GymnasiumGoalEnv]; success is the env's ``is_success``.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumGoalEnv
from taskrl.envs.pixels import check_pixel_settings, pixel_factory
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import one_of

__all__ = ["FAMILIES", "FETCH_IDS", "FetchSettings"]

#: taskrl name -> gymnasium-robotics id.
FETCH_IDS = {
    "fetchreach": "FetchReach-v4",
    "fetchpush": "FetchPush-v4",
    "fetchpickandplace": "FetchPickAndPlace-v4",
    "fetchslide": "FetchSlide-v4",
}


@dataclasses.dataclass
class FetchSettings(CameraSettings):
    """Settings of the Fetch families.

    Attributes:
        vector_strategy: ``sync`` (one process) or ``async`` (one process per copy).
        observation: what the policy sees: ``state`` (the env's vectors), ``pixels`` (the rendered frame as
            ``image``, the goals kept as vectors for relabelling) or ``pixels+state`` (both); see ``envs/pixels.py``.
        image_size: the side of the rendered picture in pixels (``pixels`` modes).
    """

    vector_strategy: Literal["sync", "async"] = "sync"
    observation: Literal["state", "pixels", "pixels+state"] = "state"
    image_size: int = 64

    def validate(self) -> None:
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")
        super().validate()
        check_pixel_settings(self)


def _maker(env_id: str):
    def make(settings: FetchSettings, request: EnvRequest) -> GymnasiumGoalEnv:
        return GymnasiumGoalEnv(
            env_id if settings.observation == "state" else pixel_factory(env_id, settings.observation, settings.image_size),
            num_envs=request.copies,
            device=request.device,
            vector_strategy=settings.vector_strategy,
            success_key="is_success",
        )

    return make


def _video(env_id: str):
    def make(settings: FetchSettings):
        from taskrl.envs.gymnasium_adapter import _make_env

        return _make_env(env_id, {"render_mode": "rgb_array"}, None)

    return make


FAMILIES = tuple(
    EnvFamily(
        name=name,
        description=f"{env_id} (gymnasium-robotics, MuJoCo; the robotics extra)",
        section="fetch",
        settings=FetchSettings,
        make=_maker(env_id),
        kind="goal",
        actions="box",
        video_env=_video(env_id),
    )
    for name, env_id in FETCH_IDS.items()
)
