"""The Fetch robotics tasks (gymnasium-robotics ``*-v4``, MuJoCo) as env families.

They need the ``robotics`` extra. Every copy is a gymnasium env behind
:class:`~taskrl.envs.gymnasium_adapter.GymnasiumGoalEnv`; success is the env's ``is_success``.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumGoalEnv
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
class FetchSettings:
    """Settings of the Fetch families.

    Attributes:
        vector_strategy: ``sync`` (one process) or ``async`` (one process per copy).
    """

    vector_strategy: Literal["sync", "async"] = "sync"

    def validate(self) -> None:
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")


def _maker(env_id: str):
    def make(settings: FetchSettings, request: EnvRequest) -> GymnasiumGoalEnv:
        return GymnasiumGoalEnv(
            env_id,
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
