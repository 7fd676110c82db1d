"""KukaGrasp: the open pybullet grasping benchmark of Quillen et al. 2018, written for this project.

"Deep Reinforcement Learning for Vision-Based Robotic Grasping: A Simulated Comparative Evaluation of
Off-Policy Methods" (Quillen, Jang, Nachum, Finn, Ibarz, Levine; ICRA 2018) defined this task to compare
grasping methods on objects never seen in training; its code is google-research ``dql_grasping``
(``grasping_env.py``, ``kuka.py``, ``configs/env_procedural``). Every constant below is theirs unless a
comment says otherwise; the code is this project's, on ``pybullet`` directly.

The task: a Kuka iiwa with a two-finger gripper over a tray holding ``num_objects`` (5) procedurally generated
objects from ``pybullet_data/random_urdfs``. The camera is over the shoulder (look-at (0.23, 0.2, 0.54),
distance 1, yaw 245, pitch -56, field of view 20), rendered at twice ``image_size`` and resized to
``image_size`` (128 -> 64, Lanczos). Actions are ``(dx, dy, dz, dyaw)`` in ``[-1, 1]^4``: the gripper's target
moves by ``0.06 *`` each of dx, dy, dz (clipped to x 0.45-0.75, y -0.22-0.22) and turns by ``0.25 * dyaw``
radians; each action runs 200 simulation steps of 1/200 s. When the gripper is at or below 0.1 m after an
action, it closes and lifts (1,000 steps) and the episode ends; otherwise it ends after 15 actions. Reward 1
when an object is above 0.2 m at the end, else 0.

What the observation holds: ``image`` (``image_size`` x ``image_size`` x 3, uint8) and ``observation``: the
gripper's position (x, y, z in metres), its yaw (radians) and the share of the 15 steps left. The benchmark's
network read the picture and the step count; the gripper's position is what the benchmark's observation
space declares beside the picture.

Where this env differs from the authors' code, and why:

- **Objects held out for real.** Their training pattern ``*[^0]`` is read by Python's glob as "``^`` or ``0``",
  so "training" drew the 100 test objects. Here ``train`` is the 900 folders whose number does not end in 0 and
  ``test`` the 100 that do (``OBJECT_SPLITS``; a test checks they are disjoint).
- **Objects redrawn.** Theirs are drawn once per env instance; here ``redraw_every`` episodes (default 1) draw
  ``num_objects`` new ones (with replacement) from the split.
- **Cheaper settling.** Theirs drops each object and steps 500 times (2.5 s of simulation) whatever happens;
  ``settle="staggered"`` (default) drops each object 60 steps after the one before (about when it has landed) and
  then simulates them all until every one is at rest (speed under 1 cm/s and 0.1 rad/s, checked every 10 steps, at
  most 500 more): about 600 steps in all. ``settle="rest"`` simulates each dropped object until it is at rest (at most
  500 steps; about 1,200 in all), and ``settle="definition"`` keeps the 2,500. ``benchmarks/kuka_grasp.py settle``
  compares where the objects end with each, from the same drops, and the random policy's success from each's
  initial states (0.43, 0.42 and 0.40 over 150 episodes, each ±0.08).
- **A missed grasp stops lifting.** Theirs always simulates the 1,000 steps of the close-and-lift;
  ``lift="decided"`` (default) stops it once it has failed for certain (`KukaGraspEnv.lift_failed`, checked every
  10 steps): both fingers shut (nothing between them) and no object touching the arm, so no object can rise any
  more. A grasp that holds something lifts the full 1,000 steps (an object above 0.2 m midway can still fall, so
  success is read at the end, as theirs). ``lift="definition"`` keeps the 1,000 steps always; both report the lift
  step at which the failure was certain (``info["lift_failed_at"]``, 0 when it never was), and
  ``benchmarks/kuka_grasp.py lift`` checks it against the full lift's outcomes. A stopped lift leaves the gripper
  low in the tray, so each reset puts the arm back at its rest pose before the objects drop, where the definition's
  reset reloads it (before commit 1d4442a, an episode after a missed grasp dropped its objects onto the gripper).
- **The next episode prepared ahead** (``reset_ahead``, with a process per copy): a copy settles its next episode's
  objects in a second simulation while it waits for the slowest of the others; the same draws in the same order, so
  the same episodes (a test compares them bit for bit with resetting in place).
- ``height_hack=True`` gives their easier variant: three actions ``(dx, dy, dyaw)`` and the gripper always
  moving down (the grasp then fires after about 3 steps). The benchmark's training config removes it; so does
  the default here.

As in their code, the loop of the 15th action stops after its first simulation step (the episode has reached
its end), so the last action barely moves the arm before the grasp check.

`random_grasp_action` is the authors' random collection policy (uniform actions, moving down with
probability 0.9 when there is no height hack).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import threading
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumVectorEnv
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import ConfigError, one_of, require

__all__ = ["OBJECT_SPLITS", "KukaGraspEnv", "KukaGraspSettings", "KukaGraspVectorEnv", "object_files", "random_grasp_action"]

#: split -> which ``random_urdfs`` folders it draws from: ``test`` the 100 whose number ends in 0
OBJECT_SPLITS = ("train", "test")
#: how the dropped objects settle (see the module docstring)
SETTLINGS = ("staggered", "rest", "definition")
STEPS = 15  # actions per episode
ACTION_REPEAT = 200  # simulation steps per action
TIME_STEP = 1.0 / 200.0
MOVE = 0.06  # metres per unit of dx, dy, dz
TURN = 0.25  # radians per unit of dyaw
GRASP_HEIGHT = 0.1  # the grasp fires at or below this gripper height
LIFT_STEPS = 1000  # simulation steps of the close-and-lift
LIFT_CHECK = 10  # lift steps between checks for a certain failure (this project's, ``lift="decided"``)
FINGERS_SHUT = 0.01  # radians: a finger joint this near 0 has nothing between it and the other (this project's)
FINGER_JOINTS = (8, 11)
SUCCESS_HEIGHT = 0.2  # an object above this after the lift is a success
DROP_SPREAD = 0.3  # objects drop at x in 0.4 + [0, 0.3], y in [-0.15, 0.15], yaw pi/2 + [0, 0.3 pi]
DROP_HEIGHT = 0.15
SETTLE_STEPS = 500  # the definition's settling steps per object (the most "rest" takes)
STAGGER_STEPS = 60  # "staggered": steps between drops (this project's; a drop from 0.15 m lands after about 50)
# the arm (dql_grasping kuka.py): base pose, rest joint angles, limits of the gripper's target, forces
ARM_BASE = (-0.1, 0.0, 0.07)
ARM_JOINTS = (
    0.006418, 0.413184, -0.011401, -1.589317, 0.005379, 1.137684, -0.006539,
    0.000048, -0.299912, 0.0, -0.000043, 0.299960, 0.0, -0.000200,
)  # fmt: skip
ARM_START = (0.537, 0.0, 0.5)  # the gripper's first target
GRIPPER_LINK = 6
X_RANGE, Y_RANGE = (0.45, 0.75), (-0.22, 0.22)
MAX_FORCE = 200.0
FINGER_FORCES = {8: 6.0, 11: 5.5, 10: 6.0, 13: 6.0}  # finger A, finger B, the two tips
CAMERA = {"look": (0.23, 0.2, 0.54), "distance": 1.0, "yaw": 245.0, "pitch": -56.0, "fov": 20.0}


@contextlib.contextmanager
def _c_stdout_silenced():
    """File descriptor 1 pointed at /dev/null for the block (what C code prints does not pass through sys.stdout)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):  # no real descriptor 1 (a captured stream): nothing to silence
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def object_files(split: str, root: str | None = None) -> list[str]:
    """The URDF files of one object split, sorted: ``train`` 900 objects, ``test`` the 100 whose folder ends in 0."""
    one_of(split, OBJECT_SPLITS, "objects", "split")
    import pybullet_data

    folder = os.path.join(root or pybullet_data.getDataPath(), "random_urdfs")
    names = sorted(n for n in os.listdir(folder) if n.isdigit())
    chosen = [n for n in names if n.endswith("0") == (split == "test")]
    return [os.path.join(folder, n, f"{n}.urdf") for n in chosen]


def random_grasp_action(generator: torch.Generator, n: int, height_hack: bool = False) -> torch.Tensor:
    """The benchmark's random collection policy for ``n`` copies: uniform in ``[-1, 1]``, and ``dz = -1`` with
    probability 0.9 (``RandomGraspingPolicyD4``); with the height hack the three actions are uniform."""
    action = torch.rand(n, 3 if height_hack else 4, generator=generator) * 2 - 1
    if not height_hack:
        down = torch.rand(n, generator=generator) < 0.9
        action[:, 2] = torch.where(down, -1.0, action[:, 2])
    return action


@dataclasses.dataclass
class KukaGraspSettings(CameraSettings):
    """Settings of the ``kukagrasp`` family (the pybullet grasping benchmark; the ``grasp`` extra).

    Attributes:
        objects: ``train`` (900 objects) or ``test`` (the 100 never seen in training).
        redraw_every: episodes between draws of new objects (1: every episode).
        num_objects: objects in the tray.
        height_hack: the easier variant: the gripper always moves down, actions ``(dx, dy, dyaw)``.
        settle: ``staggered`` (each object dropped 60 steps after the one before, then all until at rest), ``rest``
            (each dropped object until at rest, at most 500 steps) or ``definition`` (500 steps each).
        lift: ``decided`` (the close-and-lift stops once it has failed for certain: fingers shut on nothing) or
            ``definition`` (its 1,000 steps always).
        image_size: the side of the picture (rendered at twice this and resized).
        reset_ahead: simulate the next episode's initial state in a second simulation while the copy waits for its
            caller (`KukaGraspEnv`); the same draws in the same order, so the same episodes. Only with
            ``vector_strategy="async"``: one process holding every copy has no waiting to fill.
        vector_strategy: ``async`` (one process per copy: every core simulates) or ``sync`` (one process).
    """

    objects: Literal["train", "test"] = "train"
    redraw_every: int = 1
    num_objects: int = 5
    height_hack: bool = False
    settle: Literal["staggered", "rest", "definition"] = "staggered"
    lift: Literal["decided", "definition"] = "decided"
    image_size: int = 64
    reset_ahead: bool = True
    vector_strategy: Literal["sync", "async"] = "async"

    def validate(self) -> None:
        one_of(self.objects, OBJECT_SPLITS, "objects", "split")
        one_of(self.settle, SETTLINGS, "settle", "settling")
        one_of(self.lift, ("decided", "definition"), "lift", "lift")
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")
        require(self.redraw_every >= 1, "redraw_every", f"must be >= 1 episode (got {self.redraw_every})")
        require(1 <= self.num_objects <= 20, "num_objects", f"must be in 1-20 (got {self.num_objects})")
        super().validate()  # the camera

    def env_kwargs(self) -> dict[str, Any]:
        """The keyword arguments of one `KukaGraspEnv` copy."""
        fields = dataclasses.asdict(self)
        fields.pop("vector_strategy")
        return fields


class _Cancelled(Exception):
    """A background preparation told to stop (a seeded reset, or closing)."""


class _Scene:
    """One pybullet simulation of the benchmark's scene (plane, table, arm, tray), the objects in it and the gripper's
    target. While it is being prepared in the background, ``gate`` (set: it may simulate) pauses it whenever the env
    is busy, and ``cancelled`` stops it."""

    def __init__(self, pybullet: Any, root: str) -> None:
        from pybullet_utils import bullet_client

        self._pb, self._root = pybullet, root
        with _c_stdout_silenced():  # pybullet's C code prints "argv[0]=" on connecting
            self.sim = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.gate: threading.Event | None = None
        self.cancelled = False
        self.build()

    def build(self) -> None:
        """The fixed scene, in an empty simulation; no objects."""
        sim, root = self.sim, self._root
        sim.setPhysicsEngineParameter(numSolverIterations=150)
        sim.setTimeStep(TIME_STEP)
        sim.setGravity(0, 0, -10)
        sim.loadURDF(os.path.join(root, "plane.urdf"), [0, 0, -1])
        sim.loadURDF(os.path.join(root, "table/table.urdf"), [0.5, 0.0, -0.82], [0, 0, 0, 1])
        self.arm = sim.loadSDF(os.path.join(root, "kuka_iiwa/kuka_with_gripper2.sdf"))[0]
        sim.loadURDF(os.path.join(root, "tray/tray.urdf"), [0.64, 0.075, -0.19], [0, 0, 1, 0])
        self.view = sim.computeViewMatrixFromYawPitchRoll(
            CAMERA["look"], CAMERA["distance"], CAMERA["yaw"], CAMERA["pitch"], 0, 2
        )
        self.projection = sim.computeProjectionMatrixFOV(CAMERA["fov"], 1.0, 0.1, 10.0)
        self.down = sim.getQuaternionFromEuler([0, -math.pi, 0])  # the gripper's orientation, pointing down
        self.objects: list[int] = []
        self.files: list[str] = []
        self.target, self.yaw = list(ARM_START), 0.0

    def rebuild(self) -> None:
        """A fresh simulation (no contact state carried over), the fixed scene in it."""
        self.sim.resetSimulation()
        self.build()

    def step_simulation(self) -> None:
        if self.gate is not None:
            self.gate.wait()
            if self.cancelled:
                raise _Cancelled
        self.sim.stepSimulation()

    def load_objects(self, files: list[str]) -> None:
        """``files`` in the simulation, each at its parking place (kept when they are the ones already loaded)."""
        if files == self.files:
            return
        for uid in self.objects:
            self.sim.removeBody(uid)
        self.objects = [self.sim.loadURDF(f, parking_place(k)) for k, f in enumerate(files)]
        self.files = list(files)

    def settle_objects(self, poses: list[tuple[list[float], list[float]]], settle: str) -> int:
        """Drop the objects one by one from ``poses`` into the empty tray; the simulation steps it took."""
        sim = self.sim
        for k, uid in enumerate(self.objects):
            sim.resetBasePositionAndOrientation(uid, parking_place(k), [0, 0, 0, 1])
        steps = 0
        if settle == "staggered":  # each drop STAGGER_STEPS after the one before, then all of them until at rest
            for uid, (position, orientation) in zip(self.objects, poses):
                sim.resetBasePositionAndOrientation(uid, position, orientation)
                for _ in range(STAGGER_STEPS):
                    self.step_simulation()
                steps += STAGGER_STEPS
            for k in range(SETTLE_STEPS):
                if k % 10 == 0 and all(self.at_rest(uid) for uid in self.objects):
                    break
                self.step_simulation()
                steps += 1
            return steps
        for uid, (position, orientation) in zip(self.objects, poses):
            sim.resetBasePositionAndOrientation(uid, position, orientation)
            for k in range(SETTLE_STEPS):
                self.step_simulation()
                steps += 1
                if settle == "rest" and k % 10 == 9 and self.at_rest(uid):
                    break
        return steps

    def at_rest(self, uid: int) -> bool:
        linear, angular = self.sim.getBaseVelocity(uid)
        return math.hypot(*linear) < 0.01 and math.hypot(*angular) < 0.1

    def object_positions(self) -> np.ndarray:
        return np.array([self.sim.getBasePositionAndOrientation(uid)[0] for uid in self.objects])

    def reset_arm(self) -> None:
        sim, pb = self.sim, self._pb
        sim.resetBasePositionAndOrientation(self.arm, ARM_BASE, [0, 0, 0, 1])
        for joint, angle in enumerate(ARM_JOINTS):
            sim.resetJointState(self.arm, joint, angle)
        sim.setJointMotorControlArray(
            self.arm, list(range(len(ARM_JOINTS))), pb.POSITION_CONTROL,
            targetPositions=list(ARM_JOINTS), forces=[MAX_FORCE] * len(ARM_JOINTS),
        )  # fmt: skip
        self.target, self.yaw = list(ARM_START), 0.0

    def command(self, dx: float, dy: float, dz: float, dyaw: float, fingers: float) -> None:
        """Move the gripper's target (clipped to the workspace), solve the arm's joints for it, set the fingers."""
        sim, pb, target = self.sim, self._pb, self.target
        height = self.gripper_position()[2]
        target[0] = min(max(target[0] + dx, X_RANGE[0]), X_RANGE[1])
        target[1] = min(max(target[1] + dy, Y_RANGE[0]), Y_RANGE[1])
        if dz > 0 or height > GRASP_HEIGHT:
            target[2] += dz
        if height < GRASP_HEIGHT:  # the authors' arm creeps up when below the grasp height
            target[2] += 0.0001
        self.yaw += dyaw
        joints = sim.calculateInverseKinematics(
            self.arm, GRIPPER_LINK, target, self.down, jointDamping=[0.1] * 12, maxNumIterations=1
        )
        n = GRIPPER_LINK + 1
        sim.setJointMotorControlArray(
            self.arm, list(range(n)), pb.POSITION_CONTROL, targetPositions=list(joints[:n]),
            targetVelocities=[0.0] * n, forces=[MAX_FORCE] * n, positionGains=[0.03] * n, velocityGains=[1.0] * n,
        )  # fmt: skip
        sim.setJointMotorControl2(self.arm, 7, pb.POSITION_CONTROL, targetPosition=self.yaw, force=MAX_FORCE)
        for joint, force in FINGER_FORCES.items():
            finger = {8: -fingers, 11: fingers}.get(joint, 0.0)
            sim.setJointMotorControl2(self.arm, joint, pb.POSITION_CONTROL, targetPosition=finger, force=force)

    def gripper_position(self) -> tuple[float, float, float]:
        return self.sim.getLinkState(self.arm, GRIPPER_LINK)[0]

    def start_episode(self, files: list[str], poses: list[tuple[list[float], list[float]]], settle: str) -> None:
        """The part of a reset that simulates: the objects loaded and settled, the arm reset and its approach."""
        self.load_objects(files)
        for k, uid in enumerate(self.objects):
            self.sim.resetBasePositionAndOrientation(uid, parking_place(k), [0, 0, 0, 1])
        self.reset_arm()  # out of the tray before the drops: a missed grasp's lift stops with the gripper low in it
        self.settle_objects(poses, settle)
        self.reset_arm()
        self.command(0.0, 0.0, -0.3, 0.0, 0.3)  # the approach: down towards the tray, fingers open
        for _ in range(100):
            self.step_simulation()

    def close(self) -> None:
        self.sim.disconnect()


def parking_place(k: int) -> list[float]:
    """Where object ``k`` waits for its drop: on the floor far from the tray and from the others (objects overlapping
    while they wait cost more simulation than the whole drop)."""
    return [3.0 + k, 3.0, -0.8]


class KukaGraspEnv(gym.Env):
    """One copy of the benchmark (``taskrl/KukaGrasp-v0``); see the module docstring.

    With ``reset_ahead`` the next episode's initial state is simulated in a second simulation, in a background thread
    that runs only while the env waits for its caller (between `step` and `reset` calls), from the same random draws
    in the same order as without it; `reset` then hands over the prepared simulation. In a process per copy, the
    settling then fills the time a copy waits for the slowest of the others.

    Args:
        render_mode: ``rgb_array`` makes `render` return the camera picture at its rendered size.
        **settings: fields of `KukaGraspSettings` except ``vector_strategy``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, render_mode: str | None = None, **settings: Any) -> None:
        try:
            import pybullet
            import pybullet_data
        except ImportError:
            raise ConfigError("env", "kukagrasp needs pybullet: pip install 'taskrl[grasp]'") from None
        self.settings = KukaGraspSettings(**settings)
        self.settings.validate()
        self.render_mode = render_mode
        self._root = pybullet_data.getDataPath()
        self._files = object_files(self.settings.objects, self._root)
        size = self.settings.image_size
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3 if self.settings.height_hack else 4,), np.float32)
        self.observation_space = gym.spaces.Dict(
            {
                "image": gym.spaces.Box(0, 255, (size, size, 3), np.uint8),
                "observation": gym.spaces.Box(-5.0, 5.0, (5,), np.float32),
            }
        )
        self._scene = _Scene(pybullet, self._root)
        self._spare = _Scene(pybullet, self._root) if self.settings.reset_ahead else None
        self._preparing: threading.Thread | None = None
        self._prepare_error: BaseException | None = None
        self._drawn_files: list[str] = []
        self.object_names: list[str] = []
        self._episodes = 0
        self._step = 0
        self._picture: np.ndarray | None = None

    # ------------------------------------------------------------------ the scene
    def _next_draws(self) -> tuple[list[str], list[tuple[list[float], list[float]]]]:
        """The random draws of the next episode, in the order a reset makes them: its objects (new ones every
        ``redraw_every`` episodes) and their drop poses."""
        if not self._drawn_files or self._episodes % self.settings.redraw_every == 0:
            picks = self.np_random.integers(0, len(self._files), self.settings.num_objects)
            self._drawn_files = [self._files[i] for i in picks]
        self._episodes += 1
        return self._drawn_files, self.drop_poses(len(self._drawn_files))

    def drop_poses(self, count: int | None = None) -> list[tuple[list[float], list[float]]]:
        """Where each of ``count`` objects (default: those in the tray) is dropped from: the benchmark's random drop."""
        poses = []
        for _ in range(len(self._scene.objects) if count is None else count):
            u = self.np_random.random(3)
            position = [0.4 + DROP_SPREAD * u[0], DROP_SPREAD * (u[1] - 0.5), DROP_HEIGHT]
            yaw = math.pi / 2 + DROP_SPREAD * math.pi * u[2]
            poses.append((position, list(self._scene.sim.getQuaternionFromEuler([0, 0, yaw]))))
        return poses

    def settle_objects(self, poses: list[tuple[list[float], list[float]]], settle: str) -> int:
        """Drop the objects one by one from ``poses`` into the empty tray; the simulation steps it took."""
        return self._scene.settle_objects(poses, settle)

    def object_positions(self) -> np.ndarray:
        """``[num_objects, 3]``: where each object is now."""
        return self._scene.object_positions()

    def gripper_position(self) -> tuple[float, float, float]:
        """Where the gripper is (the arm's last link)."""
        return self._scene.gripper_position()

    def _prepare_next(self) -> None:
        """Start simulating the next episode's initial state in the spare simulation, in the background."""
        files, poses = self._next_draws()
        spare = self._spare
        spare.gate, spare.cancelled = threading.Event(), False
        spare.gate.set()

        def prepare() -> None:
            try:
                spare.start_episode(files, poses, self.settings.settle)
            except _Cancelled:
                pass
            except BaseException as error:  # handed to the reset that needs this simulation
                self._prepare_error = error

        self._preparing = threading.Thread(target=prepare, name="kukagrasp-reset-ahead", daemon=True)
        self._preparing.start()

    def _finish_preparing(self, cancel: bool) -> bool:
        """Wait for the background preparation (letting it run; stopped at once if ``cancel``); whether one finished."""
        if self._preparing is None:
            return False
        spare = self._spare
        spare.cancelled = cancel
        spare.gate.set()
        self._preparing.join()
        self._preparing, spare.gate = None, None
        if self._prepare_error is not None:
            error, self._prepare_error = self._prepare_error, None
            raise error
        return not cancel

    @contextlib.contextmanager
    def _busy(self):
        """The background preparation paused while the env itself simulates."""
        gate = self._spare.gate if self._spare is not None else None
        if gate is not None:
            gate.clear()
        try:
            yield
        finally:
            if gate is not None:
                gate.set()

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:  # a seeded episode starts from fresh simulations (no contact state carried over)
            self._finish_preparing(cancel=True)
            super().reset(seed=seed)
            for scene in (self._scene, self._spare):
                if scene is not None:
                    scene.rebuild()
            self._drawn_files, self._episodes = [], 0
        if self._finish_preparing(cancel=False):
            self._scene, self._spare = self._spare, self._scene
        else:
            files, poses = self._next_draws()
            self._scene.start_episode(files, poses, self.settings.settle)
        self.object_names = [os.path.basename(f)[:-5] for f in self._scene.files]
        self._step = 0
        observation = self._observation()
        if self._spare is not None:
            self._prepare_next()
        return observation, {"objects": list(self.object_names)}

    def step(self, action):
        with self._busy():
            return self._step_simulated(action)

    def _step_simulated(self, action):
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        if self.settings.height_hack:
            dx, dy, dz, dyaw = MOVE * a[0], MOVE * a[1], -MOVE, TURN * a[2]
        else:
            dx, dy, dz, dyaw = MOVE * a[0], MOVE * a[1], MOVE * a[2], TURN * a[3]
        scene = self._scene
        self._step += 1
        scene.command(dx, dy, dz, dyaw, 0.3)
        for _ in range(ACTION_REPEAT):
            scene.step_simulation()
            if self._step >= STEPS:  # the authors' loop stops at the episode's end
                break
        attempted = scene.gripper_position()[2] <= GRASP_HEIGHT
        info: dict[str, Any] = {"attempted": attempted}
        if attempted:
            info.update(self._close_and_lift())
        success = attempted and bool((scene.object_positions()[:, 2] > SUCCESS_HEIGHT).any())
        terminated = attempted or self._step >= STEPS
        info["is_success"] = success
        return self._observation(), float(success), terminated, False, info

    def _close_and_lift(self) -> dict[str, Any]:
        """Close the fingers while lifting; with ``lift="decided"`` stop once the grasp has failed for certain. The lift
        step at which it had (0: never)."""
        fingers, failed_at = 0.3, 0
        for step in range(1, LIFT_STEPS + 1):
            self._scene.command(0.0, 0.0, 0.001, 0.0, fingers)
            self._scene.step_simulation()
            fingers = max(fingers - 0.003, 0.0)
            if not failed_at and step % LIFT_CHECK == 0 and self.lift_failed():
                failed_at = step
                if self.settings.lift == "decided":
                    break
        return {"lift_failed_at": failed_at}

    def lift_failed(self) -> bool:
        """Whether the close-and-lift can no longer lift anything: both fingers shut (nothing between them) and no object
        touching the arm. Nothing rises without the gripper, so no object can reach the success height after this."""
        sim, arm = self._scene.sim, self._scene.arm
        shut = all(abs(sim.getJointState(arm, j)[0]) < FINGERS_SHUT for j in FINGER_JOINTS)
        return shut and not any(sim.getContactPoints(arm, uid) for uid in self._scene.objects)

    def _observation(self) -> dict[str, np.ndarray]:
        size, scene = self.settings.image_size, self._scene
        width, height, rgba, _, _ = scene.sim.getCameraImage(2 * size, 2 * size, scene.view, scene.projection)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]
        self._picture = rgb
        from PIL import Image  # here, not at import: `import taskrl` stays light

        image = np.asarray(Image.fromarray(rgb).resize((size, size), Image.LANCZOS))
        x, y, z = scene.gripper_position()
        state = np.array([x, y, z, scene.yaw, 1.0 - self._step / STEPS], dtype=np.float32)
        return {"image": image, "observation": state}

    def render(self):
        return None if self.render_mode != "rgb_array" or self._picture is None else self._picture.copy()

    def close(self) -> None:
        if getattr(self, "_scene", None) is None:
            return
        try:
            self._finish_preparing(cancel=True)
        finally:
            for scene in (self._scene, self._spare):
                if scene is not None:
                    scene.close()
            self._scene = self._spare = None


class KukaGraspVectorEnv(GymnasiumVectorEnv):
    """Copies of `KukaGraspEnv` behind the batched contract, with the benchmark's random policy as the
    scripted one (what ``--scripted-exploration 1`` collects with).

    Args:
        settings: the family's settings.
        num_envs: copies (one process each with ``vector_strategy="async"``).
        seed: seeds the random collection policy (the copies are seeded through ``reset(seed)``).
        device: where the tensors live.
    """

    def __init__(self, settings: KukaGraspSettings, num_envs: int, seed: int = 0, device: str | torch.device = "cpu") -> None:
        kwargs = settings.env_kwargs()
        kwargs["reset_ahead"] = settings.reset_ahead and settings.vector_strategy == "async"
        super().__init__(
            lambda: KukaGraspEnv(**kwargs),
            num_envs=num_envs,
            device=device,
            vector_strategy=settings.vector_strategy,
            success_key="is_success",
        )
        self.height_hack = settings.height_hack
        self._random = torch.Generator().manual_seed(int(seed) + 7919)

    def scripted_action(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """The benchmark's random policy (`random_grasp_action`) for every copy."""
        return random_grasp_action(self._random, self.num_envs, self.height_hack).to(self.device)


def _make(settings: KukaGraspSettings, request: EnvRequest) -> KukaGraspVectorEnv:
    if request.evaluation:  # one copy per evaluation episode: in one process, not one process each
        settings = dataclasses.replace(settings, vector_strategy="sync")
    return KukaGraspVectorEnv(settings, request.copies, seed=request.seed, device=request.device)


FAMILY = EnvFamily(
    name="kukagrasp",
    description="the pybullet grasping benchmark of Quillen et al. 2018 (Kuka arm, 5 random objects, 64x64 camera; the grasp extra)",
    section="kukagrasp",
    settings=KukaGraspSettings,
    make=_make,
    kind="plain",
    actions="box",
    images=True,
    scripted=True,
    held_out=lambda s: dataclasses.replace(s, objects="test"),
    video_env=lambda s: gym.make("taskrl/KukaGrasp-v0", render_mode="rgb_array", **s.env_kwargs()),
)
