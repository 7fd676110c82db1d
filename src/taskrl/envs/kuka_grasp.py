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
  ``benchmarks/kuka_grasp.py lift`` checks it against the full lift's outcomes.
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
        vector_strategy: ``async`` (one process per copy: every core simulates) or ``sync`` (one process).
    """

    objects: Literal["train", "test"] = "train"
    redraw_every: int = 1
    num_objects: int = 5
    height_hack: bool = False
    settle: Literal["staggered", "rest", "definition"] = "staggered"
    lift: Literal["decided", "definition"] = "decided"
    image_size: int = 64
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


class KukaGraspEnv(gym.Env):
    """One copy of the benchmark (``taskrl/KukaGrasp-v0``); see the module docstring.

    Args:
        render_mode: ``rgb_array`` makes `render` return the camera picture at its rendered size.
        **settings: fields of `KukaGraspSettings` except ``vector_strategy``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, render_mode: str | None = None, **settings: Any) -> None:
        try:
            import pybullet
            import pybullet_data
            from pybullet_utils import bullet_client
        except ImportError:
            raise ConfigError("env", "kukagrasp needs pybullet: pip install 'taskrl[grasp]'") from None
        self.settings = KukaGraspSettings(**settings)
        self.settings.validate()
        self.render_mode = render_mode
        self._pb = pybullet
        with _c_stdout_silenced():  # pybullet's C code prints "argv[0]=" on connecting
            self._sim = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
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
        self._build_scene()
        self._objects: list[int] = []
        self.object_names: list[str] = []
        self._episodes = 0
        self._picture: np.ndarray | None = None

    # ------------------------------------------------------------------ the scene
    def _build_scene(self) -> None:
        sim, root = self._sim, self._root
        sim.setPhysicsEngineParameter(numSolverIterations=150)
        sim.setTimeStep(TIME_STEP)
        sim.setGravity(0, 0, -10)
        sim.loadURDF(os.path.join(root, "plane.urdf"), [0, 0, -1])
        sim.loadURDF(os.path.join(root, "table/table.urdf"), [0.5, 0.0, -0.82], [0, 0, 0, 1])
        self._arm = sim.loadSDF(os.path.join(root, "kuka_iiwa/kuka_with_gripper2.sdf"))[0]
        sim.loadURDF(os.path.join(root, "tray/tray.urdf"), [0.64, 0.075, -0.19], [0, 0, 1, 0])
        self._view = sim.computeViewMatrixFromYawPitchRoll(
            CAMERA["look"], CAMERA["distance"], CAMERA["yaw"], CAMERA["pitch"], 0, 2
        )
        self._projection = sim.computeProjectionMatrixFOV(CAMERA["fov"], 1.0, 0.1, 10.0)
        self._arm_joints = list(range(GRIPPER_LINK + 1))
        self._down = sim.getQuaternionFromEuler([0, -math.pi, 0])  # the gripper's orientation, pointing down

    def _draw_objects(self) -> None:
        for uid in self._objects:
            self._sim.removeBody(uid)
        picks = self.np_random.integers(0, len(self._files), self.settings.num_objects)
        self.object_names = [os.path.basename(self._files[i])[:-5] for i in picks]
        self._objects = [self._sim.loadURDF(self._files[i], self._parking(k)) for k, i in enumerate(picks)]

    @staticmethod
    def _parking(k: int) -> list[float]:
        """Where object ``k`` waits for its drop: on the floor far from the tray and from the others (objects
        overlapping while they wait cost more simulation than the whole drop)."""
        return [3.0 + k, 3.0, -0.8]

    def drop_poses(self) -> list[tuple[list[float], list[float]]]:
        """Where each object is dropped from this episode (position, quaternion): the benchmark's random drop."""
        poses = []
        for _ in self._objects:
            u = self.np_random.random(3)
            position = [0.4 + DROP_SPREAD * u[0], DROP_SPREAD * (u[1] - 0.5), DROP_HEIGHT]
            poses.append((position, list(self._sim.getQuaternionFromEuler([0, 0, math.pi / 2 + DROP_SPREAD * math.pi * u[2]]))))
        return poses

    def settle_objects(self, poses: list[tuple[list[float], list[float]]], settle: str) -> int:
        """Drop the objects one by one from ``poses`` into the empty tray; the simulation steps it took."""
        for k, uid in enumerate(self._objects):
            self._sim.resetBasePositionAndOrientation(uid, self._parking(k), [0, 0, 0, 1])
        steps = 0
        if settle == "staggered":  # each drop STAGGER_STEPS after the one before, then all of them until at rest
            for uid, (position, orientation) in zip(self._objects, poses):
                self._sim.resetBasePositionAndOrientation(uid, position, orientation)
                for _ in range(STAGGER_STEPS):
                    self._sim.stepSimulation()
                steps += STAGGER_STEPS
            for k in range(SETTLE_STEPS):
                if k % 10 == 0 and all(self._at_rest(uid) for uid in self._objects):
                    break
                self._sim.stepSimulation()
                steps += 1
            return steps
        for uid, (position, orientation) in zip(self._objects, poses):
            self._sim.resetBasePositionAndOrientation(uid, position, orientation)
            for k in range(SETTLE_STEPS):
                self._sim.stepSimulation()
                steps += 1
                if settle == "rest" and k % 10 == 9 and self._at_rest(uid):
                    break
        return steps

    def _at_rest(self, uid: int) -> bool:
        linear, angular = self._sim.getBaseVelocity(uid)
        return math.hypot(*linear) < 0.01 and math.hypot(*angular) < 0.1

    def object_positions(self) -> np.ndarray:
        """``[num_objects, 3]``: where each object is now."""
        return np.array([self._sim.getBasePositionAndOrientation(uid)[0] for uid in self._objects])

    def _reset_arm(self) -> None:
        sim = self._sim
        sim.resetBasePositionAndOrientation(self._arm, ARM_BASE, [0, 0, 0, 1])
        for joint, angle in enumerate(ARM_JOINTS):
            sim.resetJointState(self._arm, joint, angle)
        sim.setJointMotorControlArray(
            self._arm, list(range(len(ARM_JOINTS))), self._pb.POSITION_CONTROL,
            targetPositions=list(ARM_JOINTS), forces=[MAX_FORCE] * len(ARM_JOINTS),
        )  # fmt: skip
        self._target = list(ARM_START)
        self._yaw = 0.0

    def _command(self, dx: float, dy: float, dz: float, dyaw: float, fingers: float) -> None:
        """Move the gripper's target (clipped to the workspace), solve the arm's joints for it, set the fingers."""
        sim = self._sim
        height = self.gripper_position()[2]
        self._target[0] = min(max(self._target[0] + dx, X_RANGE[0]), X_RANGE[1])
        self._target[1] = min(max(self._target[1] + dy, Y_RANGE[0]), Y_RANGE[1])
        if dz > 0 or height > GRASP_HEIGHT:
            self._target[2] += dz
        if height < GRASP_HEIGHT:  # the authors' arm creeps up when below the grasp height
            self._target[2] += 0.0001
        self._yaw += dyaw
        joints = sim.calculateInverseKinematics(
            self._arm, GRIPPER_LINK, self._target, self._down, jointDamping=[0.1] * 12, maxNumIterations=1
        )
        n = len(self._arm_joints)
        sim.setJointMotorControlArray(
            self._arm, self._arm_joints, self._pb.POSITION_CONTROL, targetPositions=list(joints[:n]),
            targetVelocities=[0.0] * n, forces=[MAX_FORCE] * n, positionGains=[0.03] * n, velocityGains=[1.0] * n,
        )  # fmt: skip
        sim.setJointMotorControl2(self._arm, 7, self._pb.POSITION_CONTROL, targetPosition=self._yaw, force=MAX_FORCE)
        for joint, force in FINGER_FORCES.items():
            target = {8: -fingers, 11: fingers}.get(joint, 0.0)
            sim.setJointMotorControl2(self._arm, joint, self._pb.POSITION_CONTROL, targetPosition=target, force=force)

    def gripper_position(self) -> tuple[float, float, float]:
        """Where the gripper is (the arm's last link)."""
        return self._sim.getLinkState(self._arm, GRIPPER_LINK)[0]

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:  # a seeded episode starts from a fresh simulation (no contact state carried over)
            self._sim.resetSimulation()
            self._build_scene()
            self._objects, self._episodes = [], 0
        if not self._objects or self._episodes % self.settings.redraw_every == 0:
            self._draw_objects()
        self._episodes += 1
        self.settle_objects(self.drop_poses(), self.settings.settle)
        self._reset_arm()
        self._command(0.0, 0.0, -0.3, 0.0, 0.3)  # the approach: down towards the tray, fingers open
        for _ in range(100):
            self._sim.stepSimulation()
        self._step = 0
        return self._observation(), {"objects": list(self.object_names)}

    def step(self, action):
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        if self.settings.height_hack:
            dx, dy, dz, dyaw = MOVE * a[0], MOVE * a[1], -MOVE, TURN * a[2]
        else:
            dx, dy, dz, dyaw = MOVE * a[0], MOVE * a[1], MOVE * a[2], TURN * a[3]
        self._step += 1
        self._command(dx, dy, dz, dyaw, 0.3)
        for _ in range(ACTION_REPEAT):
            self._sim.stepSimulation()
            if self._step >= STEPS:  # the authors' loop stops at the episode's end
                break
        attempted = self.gripper_position()[2] <= GRASP_HEIGHT
        info: dict[str, Any] = {"attempted": attempted}
        if attempted:
            info.update(self._close_and_lift())
        success = attempted and bool((self.object_positions()[:, 2] > SUCCESS_HEIGHT).any())
        terminated = attempted or self._step >= STEPS
        info["is_success"] = success
        return self._observation(), float(success), terminated, False, info

    def _close_and_lift(self) -> dict[str, Any]:
        """Close the fingers while lifting; with ``lift="decided"`` stop once the grasp has failed for certain. The lift
        step at which it had (0: never)."""
        fingers, failed_at = 0.3, 0
        for step in range(1, LIFT_STEPS + 1):
            self._command(0.0, 0.0, 0.001, 0.0, fingers)
            self._sim.stepSimulation()
            fingers = max(fingers - 0.003, 0.0)
            if not failed_at and step % LIFT_CHECK == 0 and self.lift_failed():
                failed_at = step
                if self.settings.lift == "decided":
                    break
        return {"lift_failed_at": failed_at}

    def lift_failed(self) -> bool:
        """Whether the close-and-lift can no longer lift anything: both fingers shut (nothing between them) and no object
        touching the arm. Nothing rises without the gripper, so no object can reach the success height after this."""
        shut = all(abs(self._sim.getJointState(self._arm, j)[0]) < FINGERS_SHUT for j in FINGER_JOINTS)
        return shut and not any(self._sim.getContactPoints(self._arm, uid) for uid in self._objects)

    def _observation(self) -> dict[str, np.ndarray]:
        size = self.settings.image_size
        width, height, rgba, _, _ = self._sim.getCameraImage(2 * size, 2 * size, self._view, self._projection)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]
        self._picture = rgb
        from PIL import Image  # here, not at import: `import taskrl` stays light

        image = np.asarray(Image.fromarray(rgb).resize((size, size), Image.LANCZOS))
        x, y, z = self.gripper_position()
        state = np.array([x, y, z, self._yaw, 1.0 - self._step / STEPS], dtype=np.float32)
        return {"image": image, "observation": state}

    def render(self):
        return None if self.render_mode != "rgb_array" or self._picture is None else self._picture.copy()

    def close(self) -> None:
        if getattr(self, "_sim", None) is not None:
            self._sim.disconnect()
            self._sim = None


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
