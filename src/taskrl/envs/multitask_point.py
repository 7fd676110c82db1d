"""Multi-task point reaching: K named target regions, the task index in the observation.

A point lives in the box ``[-1, 1]^2`` and moves by ``clip(action, -1, 1) * max_speed`` per step
(clipped to the box), as in [`PointReach`][taskrl.envs.point_reach.PointReach]. There is no goal in
the observation: each episode has a *task*, one of K named regions described in words
("Move the point into the top-left corner of the square."), and the observation says only which
one, by its index::

    {"observation": position (2-d float32), "task": int64 index into env.task_set}

Reward: ``"sparse"`` is 0 within ``radius`` of the task's region centre, else -1; ``"dense"``
is minus the distance to it. Success is being within ``radius``. Episodes last ``horizon`` (50)
steps; reaching the region does not end them unless ``terminate_on_success``.

**Why conditioning is needed.** The default regions are the four corners of the square and its
centre. From the same position, different tasks need opposite actions (towards the top-left
corner vs. the bottom-right one). The point is in at most one region at a time, so a policy that
ignores ``task`` ends at most ``1 / K`` of its episodes (uniform tasks) in the right region and
collects the sparse reward of one task only, while a policy conditioned on the task index
(one-hot, an embedding, or the sentence) reaches any region from anywhere within 20 steps and
stays there: success at the final step near 1 against at most ``1 / K``. (Success at *any* step,
Meta-World's criterion, can be partly gamed without the task by touring two or three regions
in one episode; measure conditioning with final-step success or the return.) This is the
multi-task test bed of the library: small, native and batched, and not solvable without the task.

Task assignment: ``task_sampling="uniform"`` draws each episode's task uniformly at reset;
``"fixed"`` gives copy ``i`` task ``i % K`` for every episode (handy for per-task evaluation).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import BatchedEnv, NativeEnv, Obs, StepResult
from taskrl.envs.gymnasium_env import TaskChoiceEnv
from taskrl.envs.point_reach import PointReachSettings, RewardType, _check_positive, check_point_env_args
from taskrl.envs.spec import DemoSource, EnvFamily, EnvRequest, Expert
from taskrl.tasks import TaskSet

TaskSampling = Literal["uniform", "fixed"]
TASK_SAMPLINGS = ("uniform", "fixed")

# (name, description, centre): the default regions, corners and centre of the square.
DEFAULT_REGIONS: tuple[tuple[str, str, tuple[float, float]], ...] = (
    ("top-left", "Move the point into the top-left corner of the square.", (-0.7, 0.7)),
    ("top-right", "Move the point into the top-right corner of the square.", (0.7, 0.7)),
    ("bottom-left", "Move the point into the bottom-left corner of the square.", (-0.7, -0.7)),
    ("bottom-right", "Move the point into the bottom-right corner of the square.", (0.7, -0.7)),
    ("centre", "Move the point to the centre of the square.", (0.0, 0.0)),
)


#: Other wordings of each region's task, never used in training: robustness of language prompts.
PARAPHRASES: dict[str, tuple[str, ...]] = {
    "top-left": ("Go to the upper left corner.",),
    "top-right": ("Head for the corner at the top on the right.",),
    "bottom-left": ("Drive the dot down to the lower-left corner.",),
    "bottom-right": ("Go to the lower right corner of the box.",),
    "centre": ("Stop in the middle of the square.",),
}


class MultiTaskPointReach(NativeEnv):
    """``num_envs`` copies of multi-task point reaching, stepped at once in torch.

    Args:
        num_envs: copies stepped in parallel.
        device: torch device the state lives on.
        regions: ``(name, description, (x, y))`` triples, one per task (default: the four
            corners and the centre, `DEFAULT_REGIONS`). Centres must lie in ``[-1, 1]^2``.
        horizon: steps before truncation.
        reward: ``"sparse"`` (0 within ``radius`` of the task's centre, else -1) or ``"dense"``
            (minus the distance to it).
        radius: success radius around each region centre.
        max_speed: largest move per step along each axis.
        task_sampling: ``"uniform"`` (a new random task every episode) or ``"fixed"`` (copy ``i``
            always has task ``i % K``).
        terminate_on_success: end the episode when the region is reached (default: no).
        seed: seed of the environment's generator.

    Attributes:
        task_set: the [`TaskSet`][taskrl.tasks.TaskSet] of the regions (names and descriptions).
        centres: ``[K, 2]`` region centres.
        task: ``[num_envs]`` current task of every copy.
        slot_tasks: ``[num_envs]`` task of each copy with ``task_sampling="fixed"`` (``None`` when
            uniform); [`evaluate_per_task`][taskrl.training.per_task.evaluate_per_task] uses it.
    """

    def __init__(
        self,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        regions: Sequence[tuple[str, str, Sequence[float]]] = DEFAULT_REGIONS,
        horizon: int = 50,
        reward: RewardType = "sparse",
        radius: float = 0.1,
        max_speed: float = 0.1,
        task_sampling: TaskSampling = "uniform",
        terminate_on_success: bool = False,
        seed: int | None = None,
    ) -> None:
        check_point_env_args(num_envs, horizon, reward)
        if task_sampling not in TASK_SAMPLINGS:
            raise ValueError(f"task_sampling must be one of {', '.join(TASK_SAMPLINGS)}; got {task_sampling!r}")
        _check_positive("radius", radius)
        _check_positive("max_speed", max_speed)
        regions = list(regions)
        if not regions:
            raise ValueError("regions must name at least one target region")
        centres = []
        for entry in regions:
            if len(entry) != 3 or len(entry[2]) != 2:
                raise ValueError(f"each region must be (name, description, (x, y)); got {entry!r}")
            x, y = (float(v) for v in entry[2])
            if not (-1.0 <= x <= 1.0 and -1.0 <= y <= 1.0):
                raise ValueError(f"region {entry[0]!r}: centre {(x, y)} is outside the box [-1, 1]^2")
            centres.append((x, y))
        self.task_set = TaskSet.from_pairs((name, description) for name, description, _ in regions)
        self.num_tasks = len(self.task_set)
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.horizon = horizon
        self.reward_type: RewardType = reward
        self.radius = float(radius)
        self.max_speed = float(max_speed)
        self.task_sampling: TaskSampling = task_sampling
        self.terminate_on_success = bool(terminate_on_success)
        self.centres = torch.tensor(centres, dtype=torch.float32, device=self.device)
        box = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.single_observation_space = gym.spaces.Dict({"observation": box, "task": gym.spaces.Discrete(self.num_tasks)})
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed if seed is not None else int(np.random.SeedSequence().entropy % 2**63))
        self.position = torch.zeros(num_envs, 2, dtype=torch.float32, device=self.device)
        self.task = torch.arange(num_envs, device=self.device) % self.num_tasks
        self.t = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.slot_tasks = self.task.clone() if task_sampling == "fixed" else None

    # ------------------------------------------------------------------ dynamics
    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if not n:
            return
        u = torch.rand((n, 2), generator=self.generator, device=self.device)
        self.position[mask] = u * 2.0 - 1.0
        if self.task_sampling == "uniform":
            self.task[mask] = torch.randint(self.num_tasks, (n,), generator=self.generator, device=self.device)
        self.t[mask] = 0

    def _obs(self) -> Obs:
        return {"observation": self.position.clone(), "task": self.task.clone()}

    def step(self, action: torch.Tensor) -> StepResult:
        action = torch.as_tensor(action, device=self.device, dtype=torch.float32).reshape(self.num_envs, 2)
        self.position = (self.position + action.clamp(-1.0, 1.0) * self.max_speed).clamp_(-1.0, 1.0)
        self.t += 1
        distance = self.distance_to_region(self.position, self.task)
        success = distance <= self.radius
        reward = self._reward(distance)
        return self._end_step(reward, success)

    # ------------------------------------------------------------------ task functions
    def distance_to_region(self, position: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        """Distance from each ``position [B, 2]`` to the centre of its ``task [B]``'s region."""
        centre = self.centres[task.to(self.device).long()]
        return torch.linalg.vector_norm(position.to(self.device).float() - centre, dim=-1)

    def _reward(self, distance: torch.Tensor) -> torch.Tensor:
        if self.reward_type == "dense":
            return -distance
        return (distance <= self.radius).float() - 1.0

    def compute_task_reward(self, observation: torch.Tensor, task: torch.Tensor, info: Any = None) -> torch.Tensor:
        """The reward of reaching ``observation`` (the next position) under ``task``, for any task.

        Vectorised over a batch, so a transition collected for one task can be relabelled with
        another task's reward (data sharing between tasks).
        """
        return self._reward(self.distance_to_region(observation, task))

    def render_rgb(self, index: int = 0):
        """A picture of copy ``index``: every region (its task's in green) and the point."""
        from taskrl.envs.render import draw_points

        task = int(self.task[index])
        regions = [(c.cpu().numpy(), self.radius, i == task) for i, c in enumerate(self.centres)]
        return draw_points(self.position[index].cpu().numpy(), regions)

    def compute_task_success(self, observation: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        """Whether ``observation`` lies in ``task``'s region, one bool per row."""
        return self.distance_to_region(observation, task) <= self.radius


class MultiTaskPointReachGymEnv(TaskChoiceEnv):
    """Gymnasium view of one copy of `MultiTaskPointReach` (``taskrl/MultiTaskPointReach-v0``).

    The task is drawn uniformly at every reset, or fixed by ``options={"task": i}`` (an index or a
    region name). The episode length is gymnasium's time limit (registered as 50); the wrapped
    copy never truncates by itself. ``info["is_success"]`` is reported every step.
    """

    def __init__(
        self,
        reward: RewardType = "sparse",
        radius: float = 0.1,
        max_speed: float = 0.1,
        terminate_on_success: bool = False,
        regions: Sequence[tuple[str, str, Sequence[float]]] = DEFAULT_REGIONS,
        render_mode: str | None = None,
    ) -> None:
        self._wrap_tasks(
            MultiTaskPointReach(
                num_envs=1,
                regions=regions,
                horizon=2**62,
                reward=reward,
                radius=radius,
                max_speed=max_speed,
                terminate_on_success=terminate_on_success,
                seed=0,
            ),
            render_mode,
        )


def _make_multitask_point(settings: PointReachSettings, request: EnvRequest) -> MultiTaskPointReach:
    # Evaluation: every task eval_episodes times at once, copy i always on task i % K.
    copies = len(DEFAULT_REGIONS) * request.eval_episodes if request.evaluation else request.num_envs
    return MultiTaskPointReach(
        num_envs=copies,
        device=request.device,
        reward=settings.reward,
        task_sampling="fixed" if request.evaluation else "uniform",
        terminate_on_success=settings.terminate_on_success,
        seed=request.seed,
    )


def _regions_env(settings: PointReachSettings, request: EnvRequest, names) -> MultiTaskPointReach:
    known = {r[0]: r for r in DEFAULT_REGIONS}
    return MultiTaskPointReach(
        num_envs=len(names) * request.eval_episodes,
        device=request.device,
        regions=[known[n] for n in names],
        reward=settings.reward,
        task_sampling="fixed",
        terminate_on_success=settings.terminate_on_success,
        seed=request.seed,
    )


def _pointreach_demos(tasks: Sequence[str] | None) -> DemoSource:
    """The optimal controller of every region (straight to it at full speed, then stay); episodes run their
    50 steps and count when they end inside the region."""
    regions = [r for r in DEFAULT_REGIONS if tasks is None or r[0] in tasks]
    unknown = sorted(set(tasks or ()) - {r[0] for r in DEFAULT_REGIONS})
    if unknown or not regions:
        raise ValueError(f"unknown pointreach-mt tasks {unknown}; allowed: {', '.join(r[0] for r in DEFAULT_REGIONS)}")

    def make_env(names: Sequence[str], copies: int, seed: int, after_success: int) -> BatchedEnv:
        chosen = [r for r in regions if r[0] in names]  # episodes run their 50 steps: no cut at success
        return MultiTaskPointReach(num_envs=len(chosen) * copies, regions=chosen, task_sampling="fixed", seed=seed)

    def expert(env: Any) -> Expert:
        def act(obs: dict[str, torch.Tensor]) -> torch.Tensor:
            offset = env.centres[obs["task"].long()] - obs["observation"]
            return (offset / env.max_speed).clamp(-1.0, 1.0)

        return act

    task_set = TaskSet.from_pairs((name, description) for name, description, _ in regions)
    return DemoSource("pointreach-mt", task_set, make_env, expert, "final")


FAMILY = EnvFamily(
    name="pointreach-mt",
    demos=_pointreach_demos,
    tasks_env=_regions_env,
    task_sentences=lambda settings: {n: [d, *PARAPHRASES.get(n, ())] for n, d, _ in DEFAULT_REGIONS},
    description="multi-task point reaching: 5 regions named in words, the task index in the observation, native torch",
    section="pointreach_mt",
    settings=PointReachSettings,
    make=_make_multitask_point,
    kind="multitask",
    actions="box",
    per_task_success="final",  # touring several regions must not count
    video_env=lambda s: gym.make(
        "taskrl/MultiTaskPointReach-v0", reward=s.reward, terminate_on_success=s.terminate_on_success, render_mode="rgb_array"
    ),
)
