"""Tabletop: a pusher and three coloured blocks seen from above; each task a verb on a block, named by a sentence.

BC-Z's setting at a scale that trains on a CPU: the policy sees a small camera picture of the table
(``image``, ``[size, size, 3]`` uint8, channels last) and the pusher's own position (``observation``,
proprioception, as a robot knows its arm's pose); where the blocks are is only in the picture. The task
index (``task``) names one of `TABLETOP_TASKS`:

- ``reach-<colour>``: "Move to the red block." — success when the pusher touches the block (centres
  within ``TOUCH``);
- ``push-left-<colour>`` / ``push-right-<colour>``: "Push the red block to the left." — success when the
  block's centre is past ``x = -EDGE`` / ``x = +EDGE``.

Three verbs on three blocks (red, green, blue) make nine tasks. `HELD_OUT` keeps three of them out
of imitation, one per verb and one per colour (a Latin-square diagonal), so every verb and every colour is
seen in training but never these combinations: zero-shot by description tests composition, as BC-Z's
held-out tasks did.

Dynamics: the pusher (a disc of radius ``PUSHER``) moves by ``action * MAX_SPEED`` in ``[-1, 1]^2`` per
step; a block it would overlap (blocks collide as discs of radius ``BLOCK``) is pushed out along the line
between their centres, so the pusher shoves what it runs into. Blocks start in three distinct cells of a
3x3 grid in the middle of the table (jittered), the pusher near the bottom edge. Episodes end at success
(reward 1, else 0 per step) or after ``horizon`` steps.

Scripted experts (``taskrl demos collect tabletop``): reach flies straight to the block; push goes round to
the block's far side (a waypoint beside the block, then behind it) and pushes it along ``x``. Pictures are
drawn in torch, anti-aliased, no OpenGL.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import BatchedEnv, NativeEnv, Obs, StepResult
from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_env import TaskChoiceEnv
from taskrl.envs.spec import DemoSource, EnvFamily, EnvRequest, Expert
from taskrl.errors import one_of, require
from taskrl.tasks import TaskSet

__all__ = ["HELD_OUT", "TABLETOP_TASKS", "Tabletop", "TabletopGymEnv", "TabletopSettings"]

COLOURS = {"red": (220, 50, 50), "green": (50, 180, 70), "blue": (50, 90, 230)}
TABLE = (110, 104, 96)
PUSHER_COLOUR = (240, 240, 240)
MAX_SPEED = 0.1
PUSHER = 0.08  # the pusher's radius
BLOCK = 0.1  # a block's half-side as drawn, and its radius when it collides
TOUCH = PUSHER + BLOCK + 0.03  # reach succeeds within this distance of the block's centre
EDGE = 0.6  # push succeeds when the block's centre is past x = -EDGE (left) or +EDGE (right)
VERBS = {
    "reach": ("Move to the {} block.", ("Go and touch the {} block.",)),
    "push-left": ("Push the {} block to the left.", ("Shove the {} block leftwards.",)),
    "push-right": ("Push the {} block to the right.", ("Shove the {} block rightwards.",)),
}
#: every verb on every block: ``(name, description)``, verb-major
TABLETOP_TASKS: tuple[tuple[str, str], ...] = tuple(
    (f"{verb}-{colour}", sentence.format(colour)) for verb, (sentence, _) in VERBS.items() for colour in COLOURS
)
#: the combinations never demonstrated: one per verb and one per colour
HELD_OUT = ("reach-green", "push-left-blue", "push-right-red")
#: other wordings of every task, never used in training
PARAPHRASES = {
    f"{verb}-{colour}": tuple(p.format(colour) for p in others) for verb, (_, others) in VERBS.items() for colour in COLOURS
}
_CELLS = torch.tensor([(x, y) for y in (-0.45, 0.0, 0.45) for x in (-0.3, 0.0, 0.3)])


def _parse(name: str) -> tuple[int, int]:
    """``(verb index, colour index)`` of a task name."""
    verb, _, colour = name.rpartition("-")
    return list(VERBS).index(verb), list(COLOURS).index(colour)


def move_pusher(pusher: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """``[B, 2]``: the pusher moved by ``action * MAX_SPEED`` (the action clipped to ``[-1, 1]^2``), kept on the table."""
    return (pusher + action.clamp(-1.0, 1.0) * MAX_SPEED).clamp(-1.0 + PUSHER, 1.0 - PUSHER)


def shove(pusher: torch.Tensor, blocks: torch.Tensor) -> torch.Tensor:
    """``[B, K, 2]``: each block the pusher (``[B, 2]``) overlaps pushed out along the line between their centres,
    so the pusher shoves what it runs into; blocks stay on the table."""
    offset = blocks - pusher[:, None]
    distance = torch.linalg.vector_norm(offset, dim=-1, keepdim=True).clamp(min=1e-6)
    contact = PUSHER + BLOCK
    pushed = pusher[:, None] + offset / distance * contact
    return torch.where(distance < contact, pushed, blocks).clamp(-1.0 + BLOCK, 1.0 - BLOCK)


def draw_table(blocks: torch.Tensor, colours: torch.Tensor, pusher: torch.Tensor, size: int) -> torch.Tensor:
    """``[B, size, size, 3]`` uint8: the table from above (x across, y up), square blocks (``[B, K, 2]`` centres,
    ``[K, 3]`` colours) and the round pusher (``[B, 2]``) on top, drawn anti-aliased: a pixel's colour mixes by
    how much of it a shape covers (a linear ramp one pixel wide), so a move under a pixel shows."""
    device = blocks.device
    centres = (torch.arange(size, device=device, dtype=torch.float32) + 0.5) / size * 2 - 1
    x, y = centres.view(1, 1, -1), -centres.view(1, -1, 1)  # y up the table, rows down the picture
    pixel = 2.0 / size
    image = torch.tensor(TABLE, dtype=torch.float32, device=device).expand(len(blocks), size, size, 3)
    for k in range(blocks.shape[1]):  # squares: coverage from the distance to the nearer edge
        dx, dy = (x - blocks[:, k, 0].view(-1, 1, 1)).abs(), (y - blocks[:, k, 1].view(-1, 1, 1)).abs()
        cover = ((BLOCK - torch.maximum(dx, dy)) / pixel + 0.5).clamp(0.0, 1.0)[..., None]
        image = image + cover * (colours[k] - image)
    distance = ((x - pusher[:, 0].view(-1, 1, 1)).square() + (y - pusher[:, 1].view(-1, 1, 1)).square()).sqrt()
    cover = ((PUSHER - distance) / pixel + 0.5).clamp(0.0, 1.0)[..., None]
    image = image + cover * (torch.tensor(PUSHER_COLOUR, dtype=torch.float32, device=device) - image)
    return image.round().to(torch.uint8)


class Tabletop(NativeEnv):
    """``num_envs`` tables at once (see the module docstring).

    Args:
        num_envs: copies stepped in parallel.
        tasks: the task names this env runs (default every task of `TABLETOP_TASKS`), in index order.
        image_size: the camera picture's side in pixels.
        horizon: steps before an episode is cut.
        task_sampling: ``uniform`` (a random task every episode) or ``fixed`` (copy ``i`` runs task ``i % K``).
        device: where the state lives.
        seed: seed of the env's generator.
    """

    def __init__(
        self,
        num_envs: int = 1,
        tasks: Sequence[str] | None = None,
        image_size: int = 32,
        horizon: int = 50,
        task_sampling: Literal["uniform", "fixed"] = "uniform",
        device: str | torch.device = "cpu",
        seed: int = 0,
    ) -> None:
        known = dict(TABLETOP_TASKS)
        names = list(tasks) if tasks is not None else list(known)
        unknown = [n for n in names if n not in known]
        if unknown or not names:
            raise ValueError(f"unknown tabletop tasks {unknown}; allowed: {', '.join(known)}")
        self.task_set = TaskSet.from_pairs((n, known[n]) for n in names)
        self.num_envs, self.device, self.horizon = int(num_envs), torch.device(device), int(horizon)
        self.image_size, self.terminate_on_success = int(image_size), True
        self.task_sampling = task_sampling
        parsed = torch.tensor([_parse(n) for n in names], device=self.device)
        self._verb, self._colour = parsed[:, 0], parsed[:, 1]
        size = self.image_size
        self.single_observation_space = gym.spaces.Dict(
            {
                "image": gym.spaces.Box(0, 255, (size, size, 3), np.uint8),
                "observation": gym.spaces.Box(-1.0, 1.0, (2,), np.float32),
                "task": gym.spaces.Discrete(len(names)),
            }
        )
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.generator = torch.Generator(device=self.device).manual_seed(int(seed))
        b = self.num_envs
        self.pusher = torch.zeros(b, 2, device=self.device)
        self.blocks = torch.zeros(b, len(COLOURS), 2, device=self.device)
        self.task = torch.arange(b, device=self.device) % len(names)
        self.slot_tasks = self.task.clone() if task_sampling == "fixed" else None
        self.t = torch.zeros(b, dtype=torch.long, device=self.device)
        self._colours = torch.tensor(list(COLOURS.values()), dtype=torch.float32, device=self.device)
        self._cells = _CELLS.to(self.device)

    # ------------------------------------------------------------------ state
    def _uniform(self, *shape: int) -> torch.Tensor:
        return torch.rand(shape, generator=self.generator, device=self.device)

    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if not n:
            return
        cells = self._uniform(n, len(self._cells)).argsort(1)[:, : len(COLOURS)]  # distinct cells per table
        jitter = (self._uniform(n, len(COLOURS), 2) * 2 - 1) * 0.08
        self.blocks[mask] = self._cells[cells] + jitter
        self.pusher[mask] = torch.stack([self._uniform(n) * 1.6 - 0.8, -0.85 + 0.1 * self._uniform(n)], 1)
        if self.task_sampling == "uniform":
            self.task[mask] = torch.randint(len(self.task_set), (n,), generator=self.generator, device=self.device)
        self.t[mask] = 0

    def target(self) -> torch.Tensor:
        """``[B, 2]`` the centre of the block each copy's task names."""
        return self.blocks[torch.arange(self.num_envs, device=self.device), self._colour[self.task]]

    def success(self) -> torch.Tensor:
        """Whether each copy's task is done now."""
        block, verb = self.target(), self._verb[self.task]
        touching = torch.linalg.vector_norm(block - self.pusher, dim=-1) <= TOUCH
        return torch.where(verb == 0, touching, torch.where(verb == 1, block[:, 0] <= -EDGE, block[:, 0] >= EDGE))

    def picture(self) -> torch.Tensor:
        """``[B, size, size, 3]`` uint8: the table from above, the blocks and the pusher drawn anti-aliased."""
        return draw_table(self.blocks, self._colours, self.pusher, self.image_size)

    def _obs(self) -> Obs:
        return {"image": self.picture(), "observation": self.pusher.clone(), "task": self.task.clone()}

    def step(self, action: torch.Tensor) -> StepResult:
        action = torch.as_tensor(action, device=self.device, dtype=torch.float32).reshape(self.num_envs, 2)
        self.pusher = move_pusher(self.pusher, action)
        self.blocks = shove(self.pusher, self.blocks)
        self.t += 1
        success = self.success()
        return self._end_step(success.float(), success)

    def render_rgb(self, index: int = 0) -> np.ndarray:
        """The camera's picture of copy ``index``, each pixel drawn 4x4."""
        return self.picture()[index].repeat_interleave(4, 0).repeat_interleave(4, 1).cpu().numpy()

    # ------------------------------------------------------------------ expert
    def expert(self, obs: Obs) -> torch.Tensor:
        """The scripted expert's action for every copy: reach flies to the block; push goes round to the block's
        far side (first beside it, out of its way, then behind it) and pushes it along x."""
        pusher, block = obs["observation"].to(self.device), self.target()
        verb = self._verb[obs["task"].to(self.device).long()]
        side = torch.where(verb == 1, 1.0, -1.0)  # push left: stand on the right of the block
        behind = block + torch.stack([side * (PUSHER + BLOCK + 0.02), torch.zeros_like(side)], 1)
        beside = block + torch.stack([side * (PUSHER + BLOCK + 0.05), torch.full_like(side, -(PUSHER + BLOCK + 0.08))], 1)
        # behind the block along x already (and level with it): push; else go beside it first, then behind
        level = (pusher[:, 1] - block[:, 1]).abs() < 0.04
        past = (pusher[:, 0] - block[:, 0]) * side > PUSHER + BLOCK - 0.02
        near_beside = torch.linalg.vector_norm(pusher - beside, dim=-1) < 0.05
        on_side = (pusher[:, 0] - block[:, 0]) * side > PUSHER + BLOCK
        waypoint = torch.where((on_side | near_beside)[:, None], behind, beside)
        push = torch.stack([-side, (block[:, 1] - pusher[:, 1]) / MAX_SPEED], 1)
        move = torch.where((level & past)[:, None], push, (waypoint - pusher) / MAX_SPEED)
        reach = (block - pusher) / MAX_SPEED
        return torch.where((verb == 0)[:, None], reach, move).clamp(-1.0, 1.0)


class TabletopGymEnv(TaskChoiceEnv):
    """One copy of `Tabletop` as a ``gymnasium.Env``, ``taskrl/Tabletop-v0`` (time limit 50): the task is
    drawn at every reset or fixed by ``options={"task": i}`` (an index or a name).

    Args:
        tasks: the task names, in index order (default all nine).
        image_size: the camera picture's side in pixels.
        render_mode: None or ``rgb_array``.
    """

    def __init__(self, tasks: Sequence[str] | None = None, image_size: int = 32, render_mode: str | None = None) -> None:
        self._wrap_tasks(Tabletop(num_envs=1, tasks=tasks, image_size=image_size, horizon=2**62, seed=0), render_mode)


@dataclasses.dataclass
class TabletopSettings(CameraSettings):
    """Settings of the ``tabletop`` family.

    Attributes:
        tasks: ``train`` (the six tasks left when `HELD_OUT` is taken out: what runs train and evaluate on;
            the held-out ones are evaluated with ``taskrl eval RUN --held-out``) or ``all`` (the nine).
        image_size: the camera picture's side in pixels.
        horizon: steps before an episode is cut.
    """

    tasks: Literal["train", "all"] = "train"
    image_size: int = 32
    horizon: int = 50

    def names(self) -> list[str]:
        """The task names of these settings, in index order."""
        return [n for n, _ in TABLETOP_TASKS if self.tasks == "all" or n not in HELD_OUT]

    def validate(self) -> None:
        one_of(self.tasks, ("train", "all"), "tasks", "task set")
        super().validate()  # the camera
        require(self.horizon >= 1, "horizon", f"must be >= 1 (got {self.horizon})")


def _make(settings: TabletopSettings, request: EnvRequest) -> Tabletop:
    # evaluation: every task eval_episodes times at once, copy i always on task i % K
    names = settings.names()
    copies = len(names) * request.eval_episodes if request.evaluation else request.num_envs
    return _tables(settings, request, names, copies, "fixed" if request.evaluation else "uniform")


def _tables(settings: TabletopSettings, request: EnvRequest, names, copies: int, sampling: str) -> Tabletop:
    return Tabletop(
        num_envs=copies,
        tasks=names,
        image_size=settings.image_size,
        horizon=settings.horizon,
        task_sampling=sampling,
        device=request.device,
        seed=request.seed,
    )


def _demos(tasks: Sequence[str] | None) -> DemoSource:
    """The scripted experts of the tasks (all nine by default; a dataset for held-out evaluation keeps every task,
    and the run leaves out the held-out ones with ``--held-out-tasks``); an episode counts when it succeeds."""
    names = list(tasks) if tasks else [n for n, _ in TABLETOP_TASKS]
    unknown = sorted(set(names) - dict(TABLETOP_TASKS).keys())
    if unknown:
        raise ValueError(f"unknown tabletop tasks {unknown}; allowed: {', '.join(n for n, _ in TABLETOP_TASKS)}")

    def make_env(chosen: Sequence[str], copies: int, seed: int, after_success: int, image_size: int = 32) -> BatchedEnv:
        ordered = [n for n in names if n in chosen]
        return Tabletop(num_envs=len(ordered) * copies, tasks=ordered, task_sampling="fixed", seed=seed, image_size=image_size)

    def expert(env: Any) -> Expert:
        return env.expert

    task_set = TaskSet.from_pairs((n, dict(TABLETOP_TASKS)[n]) for n in names)
    return DemoSource("tabletop", task_set, make_env, expert, "any", splits={"held_out": list(HELD_OUT)}, cameras=True)


FAMILY = EnvFamily(
    name="tabletop",
    description="a pusher and three coloured blocks seen by a camera; 9 tasks (reach / push left / push right x colour), "
    "each a sentence; scripted experts; native torch",
    section="tabletop",
    settings=TabletopSettings,
    make=_make,
    kind="multitask",
    actions="box",
    images=True,
    per_task_success="any",
    demos=_demos,
    tasks_env=lambda settings, request, names: _tables(settings, request, names, len(names) * request.eval_episodes, "fixed"),
    task_sentences=lambda settings: {n: [d, *PARAPHRASES[n]] for n, d in TABLETOP_TASKS},
    video_env=lambda s: gym.make("taskrl/Tabletop-v0", tasks=s.names(), image_size=s.image_size, render_mode="rgb_array"),
)
