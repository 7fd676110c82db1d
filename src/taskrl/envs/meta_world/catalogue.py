"""Meta-World v3's task catalogue, without Meta-World installed: the task names and orders (MT10, MT50,
ML45), one sentence per task, the task sets, and the spaces an agent is built from (`metaworld_spec`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import gymnasium as gym
import numpy as np
import torch

from taskrl.tasks import TaskSet

METAWORLD_VERSION = "v3"
METAWORLD_HORIZON = 500  # Meta-World's max_path_length
METAWORLD_NUM_GOALS = 50  # goal positions Meta-World pre-draws per task
METAWORLD_OBS_DIM = 39
METAWORLD_ACTION_DIM = 4
#: Where the goal position sits in the 39-d observation (Meta-World's ``_get_obs``: hand, gripper, objects,
#: the previous frame's 18, then the goal). ML benchmarks zero it (``_partially_observable``).
METAWORLD_GOAL = slice(36, 39)
INSTALL_HINT = "Meta-World environments need the `metaworld` extra: pip install 'taskrl[metaworld]'"

# One sentence per task, written for taskrl from what each task asks of the robot (Yu et al.,
# 2019, appendix), in Meta-World's MT50 order (its ALL_V3_ENVIRONMENTS).
METAWORLD_DESCRIPTIONS: dict[str, str] = {
    "assembly": "Pick up the nut and fit it over the peg.",
    "basketball": "Pick up the ball and dunk it into the basket.",
    "bin-picking": "Pick the puck out of one bin and place it in the other bin.",
    "box-close": "Pick up the lid and put it on the box to close it.",
    "button-press-topdown": "Press the button down from above.",
    "button-press-topdown-wall": "Reach over a wall and press the button down from above.",
    "button-press": "Press the button in from the front.",
    "button-press-wall": "Reach around a wall and press the button in from the front.",
    "coffee-button": "Push the button on the coffee machine.",
    "coffee-pull": "Pull the mug out from under the coffee machine to the goal.",
    "coffee-push": "Push the mug under the coffee machine.",
    "dial-turn": "Turn the dial around to the goal angle.",
    "disassemble": "Pull the nut up and off the peg.",
    "door-close": "Push the open door closed on its hinge.",
    "door-lock": "Turn the lock on the door down to lock it.",
    "door-open": "Pull the door open on its hinge.",
    "door-unlock": "Turn the lock on the door up to unlock it.",
    "hand-insert": "Move the gripper into the hole in the table.",
    "drawer-close": "Push the drawer closed.",
    "drawer-open": "Pull the drawer open by its handle.",
    "faucet-open": "Turn the faucet handle to open the tap.",
    "faucet-close": "Turn the faucet handle the other way to close the tap.",
    "hammer": "Pick up the hammer and drive the nail into the wall.",
    "handle-press-side": "Press the handle down from the side.",
    "handle-press": "Press the handle down from the front.",
    "handle-pull-side": "Pull the handle up from the side.",
    "handle-pull": "Pull the handle up from the front.",
    "lever-pull": "Pull the lever up until it points to the goal.",
    "pick-place-wall": "Pick up the puck, carry it over a wall and place it at the goal.",
    "pick-out-of-hole": "Pick the puck up out of the hole and lift it to the goal.",
    "pick-place": "Pick up the puck and place it at the goal position.",
    "plate-slide": "Slide the plate forward into the cabinet.",
    "plate-slide-side": "Slide the plate sideways into the cabinet.",
    "plate-slide-back": "Slide the plate back out of the cabinet.",
    "plate-slide-back-side": "Slide the plate sideways back out of the cabinet.",
    "peg-insert-side": "Pick up the peg and insert it sideways into the hole.",
    "peg-unplug-side": "Pull the peg sideways out of its socket.",
    "soccer": "Push the soccer ball into the goal.",
    "stick-push": "Grasp the stick and use it to push the thermos to the goal.",
    "stick-pull": "Grasp the stick and use it to pull the thermos to the goal.",
    "push": "Push the puck across the table to the goal.",
    "push-wall": "Push the puck around a wall to the goal.",
    "push-back": "Pull the puck back towards the robot to the goal.",
    "reach": "Move the gripper to the goal position.",
    "reach-wall": "Move the gripper over a wall to the goal position.",
    "shelf-place": "Pick up the puck and place it on the shelf.",
    "sweep-into": "Sweep the puck into the hole in the table.",
    "sweep": "Sweep the puck off the edge of the table.",
    "window-open": "Slide the window open sideways.",
    "window-close": "Slide the window closed sideways.",
}

MT50_TASKS: tuple[str, ...] = tuple(METAWORLD_DESCRIPTIONS)

#: Other wordings of the MT10 tasks and of ML45's test tasks, never seen in training: how robust a
#: language-conditioned policy is to how its task is said (``taskrl eval --held-out --prompt paraphrase``).
METAWORLD_PARAPHRASES: dict[str, tuple[str, ...]] = {
    "reach": ("Bring the robot's hand to the target.", "Put the end effector on the goal point."),
    "push": ("Slide the puck over the table until it reaches the target.", "Shove the small disc to the goal."),
    "pick-place": ("Grab the puck and set it down on the target.", "Lift the disc and put it where the goal is."),
    "door-open": ("Swing the door open.", "Open the door by pulling it around its hinge."),
    "drawer-open": ("Open the drawer.", "Grab the drawer handle and pull it out."),
    "drawer-close": ("Close the drawer.", "Shove the drawer back in."),
    "button-press-topdown": ("Push the button from the top.", "Press down on the button below the gripper."),
    "peg-insert-side": ("Grab the peg and push it into the hole from the side.", "Insert the peg horizontally into the slot."),
    "window-open": ("Open the window by sliding it.", "Push the window sideways to open it."),
    "window-close": ("Close the window by sliding it.", "Slide the window shut."),
    "bin-picking": (
        "Move the puck from the first bin into the second one.",
        "Take the disc out of its bin and drop it in the other.",
    ),
    "box-close": ("Put the lid on the box.", "Grab the cover and close the box with it."),
    "hand-insert": ("Put the gripper into the hole in the table.", "Lower the hand into the opening in the table top."),
    "door-lock": ("Lock the door by turning its lock down.", "Rotate the door's lock downwards."),
    "door-unlock": ("Unlock the door by turning its lock up.", "Rotate the door's lock upwards."),
}
# Meta-World's MT10 order (the one-hot index of each task).
MT10_TASKS: tuple[str, ...] = (
    "reach",
    "push",
    "pick-place",
    "door-open",
    "drawer-open",
    "drawer-close",
    "button-press-topdown",
    "peg-insert-side",
    "window-open",
    "window-close",
)
BENCHMARKS = ("MT1", "MT10", "MT50")
#: Meta-World's ML45 split (its ``ML45_V3``): 5 test tasks, and the other 45 in MT50's order for training.
ML45_TEST_TASKS: tuple[str, ...] = ("bin-picking", "box-close", "hand-insert", "door-lock", "door-unlock")
ML45_TRAIN_TASKS: tuple[str, ...] = tuple(n for n in MT50_TASKS if n not in ML45_TEST_TASKS)


def hide_goal(observation: torch.Tensor) -> torch.Tensor:
    """The 39-d observation (``[..., 39]``) with the goal position zeroed, as Meta-World's ML benchmarks
    (``_partially_observable``) give it; a new tensor."""
    hidden = observation.clone()
    hidden[..., METAWORLD_GOAL] = 0.0
    return hidden


def version_free(name: str) -> str:
    """``"reach-v3"`` -> ``"reach"`` (a name without a version suffix is returned as is)."""
    head, sep, tail = name.rpartition("-v")
    return head if sep and tail.isdigit() else name


def metaworld_id(name: str) -> str:
    """``"reach"`` -> ``"reach-v3"``, Meta-World's name of the task."""
    return f"{version_free(name)}-{METAWORLD_VERSION}"


def check_name(name: str) -> str:
    if not isinstance(name, str):
        raise ValueError(f"a Meta-World task name must be a string, got {name!r}")
    base = version_free(name)
    if base not in METAWORLD_DESCRIPTIONS:
        raise ValueError(f"unknown Meta-World task {name!r}; allowed names: {', '.join(MT50_TASKS)}")
    if base != name and not name.endswith(f"-{METAWORLD_VERSION}"):
        raise ValueError(
            f"Meta-World task {name!r}: taskrl uses Meta-World {METAWORLD_VERSION}; write {base!r} or {metaworld_id(base)!r}"
        )
    return base


def metaworld_task_set(benchmark: str | Sequence[str] = "MT10", task: str | None = None) -> TaskSet:
    """The task set of ``"MT1"`` (with ``task``), ``"MT10"``, ``"MT50"`` or a list of task names.

    Names may carry Meta-World's version suffix (``reach-v3``); the task set's names never do.
    The order is Meta-World's (MT10, MT50) or the list's, and fixes each task's index.
    """
    if isinstance(benchmark, str):
        if benchmark not in BENCHMARKS:
            raise ValueError(f"benchmark must be one of {', '.join(BENCHMARKS)} or a list of task names; got {benchmark!r}")
        if benchmark == "MT1":
            if task is None:
                raise ValueError(f"MT1 needs task=<name>; allowed names: {', '.join(MT50_TASKS)}")
            names: list[str] = [check_name(task)]
        else:
            if task is not None:
                raise ValueError(f"task={task!r} applies to MT1 only (got benchmark={benchmark!r})")
            names = list(MT10_TASKS if benchmark == "MT10" else MT50_TASKS)
    else:
        if task is not None:
            raise ValueError("task applies to MT1 only; a custom benchmark is a list of task names")
        names = [check_name(n) for n in benchmark]
        if not names:
            raise ValueError("a custom Meta-World benchmark needs at least one task name")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"a custom Meta-World benchmark lists tasks more than once: {', '.join(repeated)}")
    return TaskSet.from_pairs((n, METAWORLD_DESCRIPTIONS[n]) for n in names)


@dataclasses.dataclass
class MetaWorldSpec:
    """What an agent is built from — the task set and the spaces of `MetaWorldMultiTaskEnv` —
    without building the env (each task's MuJoCo model and goal draws take seconds), e.g. to load a
    trained agent. ``test_metaworld_tasks`` checks that it matches a real env."""

    task_set: TaskSet
    single_observation_space: gym.spaces.Dict
    single_action_space: gym.spaces.Box
    hidden_goal: bool = False

    def close(self) -> None:
        """Nothing to release (the same call as on an env)."""


def metaworld_spec(
    benchmark: str | Sequence[str] = "MT10",
    task: str | None = None,
    hidden_goal: bool = False,
    observation: str = "state",
    image_size: int = 64,
) -> MetaWorldSpec:
    """The `MetaWorldSpec` of a benchmark (arguments as `metaworld_task_set` and
    `MetaWorldMultiTaskEnv`)."""
    task_set = metaworld_task_set(benchmark, task)
    entries: dict[str, gym.spaces.Space] = {"task": gym.spaces.Discrete(len(task_set))}
    if observation != "pixels":
        entries = {"observation": gym.spaces.Box(-np.inf, np.inf, shape=(METAWORLD_OBS_DIM,), dtype=np.float32), **entries}
    if observation != "state":
        entries["image"] = gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
    return MetaWorldSpec(
        task_set,
        gym.spaces.Dict(entries),
        gym.spaces.Box(-1.0, 1.0, shape=(METAWORLD_ACTION_DIM,), dtype=np.float32),
        hidden_goal,
    )
