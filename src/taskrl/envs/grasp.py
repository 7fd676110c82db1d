"""Grasp: QT-Opt's bin seen from above, batched in torch, rendered without OpenGL.

Each copy is a square bin ``[0, 1]^2`` holding ``num_objects`` objects of varied shape, size, colour and
orientation, and a parallel-jaw gripper above it. The observation is what an over-the-shoulder camera
would give at a small scale: a ``image_size x image_size`` RGB picture of the bin from above, gripper
included (uint8, channels last as gymnasium's image spaces are), beside a small state vector
(``observation``: the gripper's pose and the time left).

Actions (QT-Opt's, in the plane): ``[dx, dy, dyaw, close]`` in ``[-1, 1]^4``: the gripper moves by up to
``max_move`` in x and y and turns by up to ``max_turn`` about the vertical axis; ``close > 0`` closes the
jaws, which ends the attempt: the gripper lifts and the simulator checks the hold.

A closed gripper holds an object when both hold:

- its centre is over the object's spine: within ``tolerance`` of the object's long axis, and along it no
  further than the object's half-length minus its half-width (a disc's spine is its centre);
- the object's extent along the closing direction fits between the open jaws (``opening``): a bar or an
  ellipse fits only across the fingers; a disc at any yaw; a square of half-side ``h`` at a yaw where
  ``2h (|cos| + |sin|)`` fits, which as sampled (``h`` 0.052-0.065 against the 0.14 opening) is face on and never
  corner to corner: yaw matters for every square and elongated object.

The default ``tolerance`` (0.06) is the fair bin's: uniformly random actions hold in 5.4% of attempts on the
training objects and 6.4% on the held-out ones (``benchmarks/grasp_random.py``).

Reward 1 at the end of a successful attempt, 0 otherwise; an episode is one attempt (it ends at the close
or after ``horizon`` steps without one; either way it terminates: the time left is part of the state).

Object sets: ``train`` objects are discs, squares and bars in red, green, blue and yellow; ``held_out``
objects are never seen in training: ellipses in any colour, and the training shapes in purple, cyan,
orange and white.

Success detection (the lecture's): after an attempt the gripper moves over the bin and opens. The
camera takes the bin before and after it opens; whatever was held drops back into the bin, so the two
pictures differ where it lands. `detect_grasp` says whether something was held from those two
pictures alone (each under its own lighting and sensor noise), and ``reward="detector"`` trains on its
labels instead of the simulator's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import NativeEnv, Obs, StepResult
from taskrl.envs.camera import CameraSettings
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import one_of, require
from taskrl.types import PictureCoordinate, PicturePose

__all__ = ["GRASP_OBJECT_SETS", "Grasp", "GraspGymEnv", "GraspSettings", "detect_grasp", "scripted_attempts"]

#: shape ids: 0 disc, 1 square, 2 bar, 3 ellipse (rectangles are 1 and 2; 0 and 3 are ellipses)
SHAPES = ("disc", "square", "bar", "ellipse")
#: (half-length low, high), (half-width low, high) of each shape (a disc and a square: half-width = half-length)
#: against the 0.14 opening: a square of half-side 0.052-0.065 fits face on (0.104-0.13) and never corner to corner
#: (0.147-0.184), and bars and ellipses longer than 0.14 fit only across, so yaw matters for every square and
#: elongated object; a disc fits at any yaw
SIZES = {
    "disc": ((0.04, 0.06), None),
    "square": ((0.052, 0.065), None),
    "bar": ((0.08, 0.12), (0.02, 0.03)),
    "ellipse": ((0.075, 0.10), (0.025, 0.035)),
}
COLOURS = {
    "red": (220, 40, 40),
    "green": (40, 180, 60),
    "blue": (40, 80, 220),
    "yellow": (230, 210, 40),
    "purple": (150, 60, 190),
    "cyan": (40, 200, 210),
    "orange": (240, 140, 30),
    "white": (240, 240, 240),
}
TRAIN_COLOURS = ("red", "green", "blue", "yellow")
HELD_OUT_COLOURS = ("purple", "cyan", "orange", "white")
#: object set -> the (shape, colour) pairs it draws from
GRASP_OBJECT_SETS: dict[str, tuple[tuple[str, str], ...]] = {
    "train": tuple((s, c) for s in ("disc", "square", "bar") for c in TRAIN_COLOURS),
    "held_out": tuple(("ellipse", c) for c in COLOURS)
    + tuple((s, c) for s in ("disc", "square", "bar") for c in HELD_OUT_COLOURS),
}
FLOOR = (128, 112, 96)  # the bin's floor
FINGER = (40, 40, 40)
FINGER_HALF = (0.012, 0.03)  # a finger's half-size across and along the jaw


@dataclasses.dataclass
class GraspSettings(CameraSettings):
    """Settings of the grasp env.

    Attributes:
        objects: ``train`` or ``held_out`` (shapes and colours never in ``train``).
        num_objects: objects in the bin.
        image_size: the camera picture's side in pixels.
        horizon: steps of an attempt before it ends without a close.
        reward: ``simulator`` (the hold the simulator checks) or ``detector`` (what `detect_grasp`
            reads from the pictures before and after the gripper opens over the bin).
        max_move: largest move of the gripper per step in x and y (the bin is 1 wide).
        max_turn: largest turn of the gripper per step, radians.
        opening: the open jaws' gap.
        tolerance: how far off an object's spine the gripper's centre may be and still hold it.
    """

    objects: Literal["train", "held_out"] = "train"
    num_objects: int = 3
    image_size: int = 64
    horizon: int = 8
    reward: Literal["simulator", "detector"] = "simulator"
    max_move: float = 0.1
    max_turn: float = math.pi / 6
    opening: float = 0.14
    tolerance: float = 0.06

    def validate(self) -> None:
        one_of(self.objects, tuple(GRASP_OBJECT_SETS), "objects", "object set")
        one_of(self.reward, ("simulator", "detector"), "reward", "reward")
        require(1 <= self.num_objects <= 8, "num_objects", f"must be in 1..8 (got {self.num_objects})")
        super().validate()  # the camera
        require(self.horizon >= 1, "horizon", f"must be >= 1 (got {self.horizon})")
        require(self.max_move > 0 and self.max_turn > 0, "max_move", "max_move and max_turn must be > 0")
        require(0 < self.opening <= 1, "opening", f"must be in (0, 1] of the bin (got {self.opening})")
        require(0 < self.tolerance < self.opening / 2, "tolerance", f"must be in (0, opening / 2) (got {self.tolerance})")


def _pack(rgb: tuple[int, int, int]) -> int:
    """An RGB colour as one int32 whose little-endian bytes are R, G, B, 0."""
    return rgb[0] | rgb[1] << 8 | rgb[2] << 16


def covers(
    x: torch.Tensor, y: torch.Tensor, centre: torch.Tensor, angle: torch.Tensor, half: torch.Tensor, ellipse: torch.Tensor
) -> torch.Tensor:
    """Whether the points ``(x, y)`` (``[b, ...]`` each, broadcast together) lie inside each row's shape: an ellipse
    (``ellipse`` true) or a rectangle of half-length and half-width ``half`` (``[b, 2]``) turned by ``angle`` (``[b]``)
    about ``centre`` (``[b, 2]``). The camera paints a pixel with a shape when the pixel's centre is inside it."""
    view = (-1,) + (1,) * (x.dim() - 1)
    dx, dy = x - centre[:, 0].view(view), y - centre[:, 1].view(view)
    cos, sin = torch.cos(angle).view(view), torch.sin(angle).view(view)
    u = (dx * cos + dy * sin).abs() / half[:, 0].view(view)
    v = (-dx * sin + dy * cos).abs() / half[:, 1].view(view)
    return torch.where(ellipse.view(view), u * u + v * v <= 1.0, torch.maximum(u, v) <= 1.0)


def fits_between_jaws(half: torch.Tensor, turn: torch.Tensor, ellipse: torch.Tensor | bool, opening: float) -> torch.Tensor:
    """Whether an object of half-length and half-width ``half`` (``[..., 2]``) fits between jaws open by ``opening``
    when they close along a direction ``turn`` off its long axis: its extent along that direction (an ellipse's, or a
    rectangle's, by ``ellipse``), broadcast over ``half[..., 0]``, ``turn`` and ``ellipse``."""
    length, width = half[..., 0], half[..., 1]
    c, n = torch.cos(turn).abs(), torch.sin(turn).abs()
    extent = torch.where(torch.as_tensor(ellipse), torch.sqrt((length * c) ** 2 + (width * n) ** 2), length * c + width * n)
    return extent <= opening / 2


def detect_grasp(
    before: torch.Tensor, after: torch.Tensor, block: int = 4, changed: float = 40.0, min_blocks: int = 1
) -> torch.Tensor:
    """Whether something was held, from the bin's pictures before and after the gripper opens over it.

    Each picture is divided by its own median brightness (the lighting differs between the two), then
    averaged over ``block x block`` pixel blocks (sensor noise averages out, a dropped object does not); a
    block has changed when its colour moved by more than ``changed`` (summed over the channels, 0-255
    scale), and something dropped when at least ``min_blocks`` blocks changed.

    Args:
        before, after: ``[B, H, W, 3]`` uint8 pictures.
    Returns:
        ``[B]`` bool.
    """

    def normalised(image: torch.Tensor) -> torch.Tensor:
        x = image.float().permute(0, 3, 1, 2)
        level = x.flatten(1).median(dim=1).values.clamp(min=1.0)
        x = x * (float(sum(FLOOR)) / 3 / level).view(-1, 1, 1, 1)
        return torch.nn.functional.avg_pool2d(x, block, ceil_mode=True)

    moved = (normalised(after) - normalised(before)).abs().sum(1) > changed
    return moved.flatten(1).sum(1) >= min_blocks


class Grasp(NativeEnv):
    """``num_envs`` bins at once (see the module docstring).

    Observations: ``image`` ``[B, H, W, 3]`` uint8 and ``observation`` ``[B, 5]`` (gripper x, y in [0, 1], cos and
    sin of twice its yaw, as a parallel jaw is the same turned by pi, and the share of the attempt's steps
    left). ``info`` at every step: ``is_success`` (held, by the simulator), ``attempted`` (closed this
    step); where an attempt ended, ``detected`` (`detect_grasp`'s answer) and the two pictures
    ``bin_before`` / ``bin_after`` (zeros elsewhere).
    """

    horizon_is_terminal = True  # the time left is observed

    def __init__(
        self, settings: GraspSettings | None = None, num_envs: int = 1, seed: int = 0, device: str | torch.device = "cpu"
    ) -> None:
        self.settings = s = settings or GraspSettings()
        s.validate()
        self.num_envs, self.device, self.horizon = num_envs, torch.device(device), s.horizon
        self.terminate_on_success = True
        self.generator = torch.Generator(device=self.device).manual_seed(seed)
        size, k = s.image_size, s.num_objects
        self.single_observation_space = gym.spaces.Dict(
            {
                "image": gym.spaces.Box(0, 255, (size, size, 3), np.uint8),
                "observation": gym.spaces.Box(-1.0, 1.0, (5,), np.float32),
            }
        )
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
        pairs = GRASP_OBJECT_SETS[s.objects]
        self._pair_shape = torch.tensor([SHAPES.index(p[0]) for p in pairs], device=self.device)
        self._pair_colour = torch.tensor([COLOURS[p[1]] for p in pairs], dtype=torch.float32, device=self.device)
        self._pair_packed = torch.tensor([_pack(COLOURS[p[1]]) for p in pairs], dtype=torch.int32, device=self.device)
        b = num_envs
        self.t = torch.zeros(b, dtype=torch.long, device=self.device)
        self.gripper = torch.zeros(b, 2, device=self.device)
        self.yaw = torch.zeros(b, device=self.device)
        self.centre = torch.zeros(b, k, 2, device=self.device)
        self.angle = torch.zeros(b, k, device=self.device)
        self.half = torch.zeros(b, k, 2, device=self.device)  # half-length, half-width
        self.shape = torch.zeros(b, k, dtype=torch.long, device=self.device)
        self.colour = torch.zeros(b, k, 3, device=self.device)
        self.packed = torch.zeros(b, k, dtype=torch.int32, device=self.device)  # the colour as _pack makes it

    # ------------------------------------------------------------------ state
    def _uniform(self, *shape: int) -> torch.Tensor:
        return torch.rand(shape, generator=self.generator, device=self.device)

    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if n == 0:
            return
        k = self.settings.num_objects
        pair = torch.randint(len(self._pair_shape), (n, k), generator=self.generator, device=self.device)
        shape = self._pair_shape[pair]
        half = torch.zeros(n, k, 2, device=self.device)
        for i, name in enumerate(SHAPES):
            (lo, hi), width = SIZES[name]
            length = lo + (hi - lo) * self._uniform(n, k)
            w = length if width is None else width[0] + (width[1] - width[0]) * self._uniform(n, k)
            is_shape = shape == i
            half[..., 0] = torch.where(is_shape, length, half[..., 0])
            half[..., 1] = torch.where(is_shape, w, half[..., 1])
        self.shape[mask], self.half[mask], self.colour[mask] = shape, half, self._pair_colour[pair]
        self.packed[mask] = self._pair_packed[pair]
        self.centre[mask] = 0.15 + 0.7 * self._uniform(n, k, 2)
        self.angle[mask] = math.pi * self._uniform(n, k)
        self.gripper[mask] = 0.3 + 0.4 * self._uniform(n, 2)
        self.yaw[mask] = math.pi * self._uniform(n)
        self.t[mask] = 0

    @property
    def picture_coordinates(self) -> tuple[PictureCoordinate, ...]:
        """The state's gripper x and y are positions in the picture's frame: a pixel's centre is at x = (column + 0.5) /
        size and y = (row + 0.5) / size of the bin (what a shift moves with the picture, ``--shift-coordinates``)."""
        per_pixel = 1.0 / self.settings.image_size
        return (PictureCoordinate("observation", 0, "col", per_pixel), PictureCoordinate("observation", 1, "row", per_pixel))

    @property
    def picture_pose(self) -> PicturePose:
        """The gripper's pose in the picture's frame: x, y as `picture_coordinates` gives them, and the cosine and sine
        of twice the yaw, the angle of the line the jaws close along from the columns axis towards the rows axis (what
        QT-Opt's ``fusion=glimpse`` turns the picture by)."""
        return PicturePose("observation", 0, 1, 2, 3, turns=2)

    def _obs(self) -> Obs:
        state = torch.cat(
            [
                self.gripper,
                torch.cos(2 * self.yaw)[:, None],
                torch.sin(2 * self.yaw)[:, None],
                (1 - self.t.float() / self.horizon)[:, None],
            ],
            1,
        )
        return {"observation": state, "image": self.render()}

    # ------------------------------------------------------------------ grasping
    def holdable(self) -> torch.Tensor:
        """``[B, K]``: whether closing the gripper where it is now would hold each object."""
        on_spine, fits = self.hold_conditions()
        return on_spine & fits

    def hold_conditions(
        self, gripper: torch.Tensor | None = None, yaw: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``([B, K], [B, K])``: the two conditions of a hold (module docstring) for each object, were the gripper to
        close at ``gripper`` (``[B, 2]``) and ``yaw`` (``[B]``), by default where it is now: its centre is over the
        object's spine, and the object fits between the open jaws at that yaw."""
        s = self.settings
        yaw = self.yaw if yaw is None else yaw
        along, across = self.spine_offsets(gripper)
        length, width = self.half.unbind(-1)
        on_spine = (along <= (length - width).clamp(min=0) + s.tolerance) & (across <= s.tolerance)
        turn = yaw[:, None] - self.angle  # the closing direction against the object's long axis
        ellipse = (self.shape == 0) | (self.shape == 3)
        return on_spine, fits_between_jaws(self.half, turn, ellipse, s.opening)

    def spine_offsets(self, gripper: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``([B, K], [B, K])``: how far ``gripper`` (default: where it is) lies from each object's centre along the
        object's long axis and across it (absolute values)."""
        offset = (self.gripper if gripper is None else gripper)[:, None] - self.centre  # [B, K, 2]
        axis = torch.stack([torch.cos(self.angle), torch.sin(self.angle)], -1)
        along = (offset * axis).sum(-1).abs()
        across = (offset[..., 0] * -axis[..., 1] + offset[..., 1] * axis[..., 0]).abs()
        return along, across

    def moved(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(gripper [B, 2], yaw [B])``: where ``action`` (``[B, 4]`` in the box) moves and turns the gripper, before
        its close is checked."""
        s = self.settings
        gripper = (self.gripper + s.max_move * action[:, :2]).clamp(0.0, 1.0)
        return gripper, torch.remainder(self.yaw + s.max_turn * action[:, 2], math.pi)

    def step(self, action: torch.Tensor) -> StepResult:
        s = self.settings
        action = torch.as_tensor(action, device=self.device, dtype=torch.float32).reshape(self.num_envs, 4).clamp(-1, 1)
        self.gripper, self.yaw = self.moved(action)
        self.t += 1
        closed = action[:, 3] > 0
        holdable = self.holdable() & closed[:, None]
        held = holdable.any(1)
        extra: dict[str, Any] = {"attempted": closed}
        detected = torch.zeros_like(held)
        before = after = None
        if bool(closed.any()):
            before, after = self._drop_pictures(holdable, closed)
            detected[closed] = detect_grasp(before[closed], after[closed])
        label = detected if s.reward == "detector" else held
        obs, reward, terminated, truncated, info = self._end_step(label.float(), held, failed=closed & ~held)
        info.update(extra, is_success=held, detected=detected)
        zeros = torch.zeros(self.num_envs, *self.single_observation_space["image"].shape, dtype=torch.uint8, device=self.device)
        info["bin_before"] = before if before is not None else zeros
        info["bin_after"] = after if after is not None else zeros
        return obs, reward, terminated, truncated, info

    def _drop_pictures(self, holdable: torch.Tensor, closed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The bin from above without the gripper, before and after the jaws open over it: the held object
        (the nearest holdable one) is out of the picture, then lies where it dropped."""
        distance = (self.gripper[:, None] - self.centre).norm(dim=-1).masked_fill(~holdable, math.inf)
        lifted = torch.nn.functional.one_hot(distance.argmin(1), self.settings.num_objects).bool() & holdable.any(1)[:, None]
        before = self.render(hidden=lifted, gripper=False, noisy=True)
        landed, turned = 0.15 + 0.7 * self._uniform(self.num_envs, 2), math.pi * self._uniform(self.num_envs)
        self.centre = torch.where(lifted[..., None], landed[:, None], self.centre)
        self.angle = torch.where(lifted, turned[:, None], self.angle)
        after = self.render(gripper=False, noisy=True)
        return before, after

    # ------------------------------------------------------------------ scripted exploration
    def scripted_action(self, obs: Obs, aim_noise: float = 0.08) -> torch.Tensor:
        """``[B, 4]``: a scripted grasp for exploration, told the objects' positions by the simulator (which a robot's
        scripted policy is not; QT-Opt's paper reports its own scripted exploration only as succeeding in 15-30% of
        attempts): move over the nearest object's centre, turn the jaws across its long axis (squares: along a side),
        close when there. Each attempt aims off by a normal offset of ``aim_noise`` per axis and ``aim_noise / 0.04 x
        15`` degrees of yaw, drawn when it starts from the policy's own generator (the env's random stream is
        untouched); at the default 0.08 it holds in about a quarter of its attempts (``benchmarks/grasp_env.py --part
        scripted``), within the paper's 15-30%; at 0 in all."""
        b, s = self.num_envs, self.settings
        if getattr(self, "_aim", None) is None:
            self._aim_generator = torch.Generator(device=self.device).manual_seed(int(self.generator.initial_seed()) + 1)
            self._aim, self._aim_turn = torch.zeros(b, 2, device=self.device), torch.zeros(b, device=self.device)
        start = self.t == 0
        if bool(start.any()):
            n = int(start.sum())
            noise = torch.randn(n, 3, generator=self._aim_generator, device=self.device)
            # the yaw errs with the aim: 15 degrees at 0.04, none at 0 (a square turned 15 degrees no longer fits)
            self._aim[start], self._aim_turn[start] = aim_noise * noise[:, :2], math.radians(15) * aim_noise / 0.04 * noise[:, 2]
        nearest = (self.gripper[:, None] - self.centre).norm(dim=-1).argmin(1)
        rows = torch.arange(b, device=self.device)
        target = self.centre[rows, nearest] + self._aim
        elongated = (self.shape[rows, nearest] == 2) | (self.shape[rows, nearest] == 3)
        yaw = self.angle[rows, nearest] + torch.where(elongated, math.pi / 2, 0.0) + self._aim_turn
        turn = torch.remainder(yaw - self.yaw + math.pi / 2, math.pi) - math.pi / 2  # a jaw turned by pi is the same
        turn = torch.where(self.shape[rows, nearest] == 0, torch.zeros_like(turn), turn)  # a disc fits any way
        move = (target - self.gripper) / s.max_move
        there = (move.abs() < 0.1).all(1) & (turn.abs() < 0.05)
        last_step = self.t >= self.horizon - 1
        close = torch.where(there | last_step, 1.0, -1.0)
        return torch.cat([move.clamp(-1, 1), (turn / s.max_turn).clamp(-1, 1)[:, None], close[:, None]], 1)

    # ------------------------------------------------------------------ camera
    def render(
        self, hidden: torch.Tensor | None = None, gripper: bool = True, noisy: bool = False, chunk: int = 256
    ) -> torch.Tensor:
        """``[B, H, W, 3]`` uint8: the bin from above, objects in order (later ones on top), then the gripper.

        ``hidden`` (``[B, K]``) leaves objects out; ``noisy`` adds the detector's camera: a lighting level
        per picture (x0.85 to x1.15) and per-pixel sensor noise (std 6).
        """
        return torch.cat(
            [self._render(i, min(i + chunk, self.num_envs), hidden, gripper, noisy) for i in range(0, self.num_envs, chunk)]
        )

    def _render(self, lo: int, hi: int, hidden: torch.Tensor | None, gripper: bool, noisy: bool) -> torch.Tensor:
        size = self.settings.image_size
        b, p = hi - lo, size * size
        # colours packed in one int32 per pixel (R, G, B, 0 bytes), painted by one gather / scatter per shape;
        # one extra pixel per picture takes the window pixels that fall outside the picture
        image = torch.full((b, p + 1), _pack(FLOOR), dtype=torch.int32, device=self.device)
        shown = None if hidden is None else ~hidden[lo:hi]
        ellipse = (self.shape[lo:hi] == 0) | (self.shape[lo:hi] == 3)
        for k in range(self.settings.num_objects):
            half = self.half[lo:hi, k]
            visible = None if shown is None else shown[:, k]
            self._paint(image, self.centre[lo:hi, k], self.angle[lo:hi, k], half, ellipse[:, k], self.packed[lo:hi, k], visible)
        if gripper:
            yaw = self.yaw[lo:hi]
            jaw = torch.stack([torch.cos(yaw), torch.sin(yaw)], -1)  # the closing direction
            finger = torch.tensor(FINGER_HALF, device=self.device).expand(b, 2)
            no = torch.zeros(b, dtype=torch.bool, device=self.device)
            colour = torch.full((b,), _pack(FINGER), dtype=torch.int32, device=self.device)
            for side in (-1.0, 1.0):
                at = self.gripper[lo:hi] + side * (self.settings.opening / 2) * jaw
                self._paint(image, at, yaw, finger, no, colour, None)
        image = image[:, :p].contiguous().view(torch.uint8).view(b, p, 4)[..., :3]  # little-endian bytes: R, G, B
        if noisy:
            level = 0.85 + 0.3 * torch.rand(b, 1, 1, generator=self.generator, device=self.device)
            noise = 6.0 * torch.randn(image.shape, generator=self.generator, device=self.device)
            image = (image.float() * level + noise).clamp(0, 255).to(torch.uint8)
        return image.reshape(b, size, size, 3)

    def _paint(
        self,
        image: torch.Tensor,
        centre: torch.Tensor,
        angle: torch.Tensor,
        half: torch.Tensor,
        ellipse: torch.Tensor,
        colour: torch.Tensor,
        visible: torch.Tensor | None,
    ) -> None:
        """Paint one shape per picture (``[b]`` rows of each argument) into ``image`` ``[b, P + 1]`` (packed colours) in place,
        looking only at the window of pixels around it (objects cover a few percent of the bin)."""
        size = self.settings.image_size
        reach = half.norm(dim=-1)  # [b]: the farthest a point of the shape is from its centre
        window = int(math.ceil(2 * float(reach.max()) * size)) + 2
        offsets = torch.arange(window, device=self.device)
        first = torch.floor((centre - reach[:, None]) * size).long()  # [b, 2] (column, row) of the window's corner
        col = first[:, 0:1, None] + offsets[None, None, :]  # [b, 1, w]
        row = first[:, 1:2, None] + offsets[None, :, None]  # [b, w, 1]
        inside = covers((col.float() + 0.5) / size, (row.float() + 0.5) / size, centre, angle, half, ellipse)  # [b, w, w]
        in_picture = (col >= 0) & (col < size) & (row >= 0) & (row < size)
        inside = inside & in_picture
        if visible is not None:
            inside = inside & visible[:, None, None]
        index = torch.where(in_picture, row * size + col, size * size).reshape(len(centre), -1)
        painted = torch.where(inside.reshape(len(centre), -1), colour[:, None], image.gather(1, index))
        image.scatter_(1, index, painted)

    def render_rgb(self, index: int = 0) -> np.ndarray:
        """Copy ``index``'s camera picture (what ``eval --video`` records)."""
        return self.render()[index].cpu().numpy()


def scripted_attempts(env: Grasp, steps: int = 40, aim_noise: float = 0.08, seed: int = 0) -> tuple[int, int]:
    """``(attempts, held)``: the attempts `Grasp.scripted_action` finished in ``steps`` steps of every bin of
    ``env`` (reset with ``seed``), and how many of them held an object."""
    obs = env.reset(seed=seed)
    attempts = held = 0
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(env.scripted_action(obs, aim_noise=aim_noise))
        done = terminated | truncated
        attempts, held = attempts + int(done.sum()), held + int(info["is_success"][done].sum())
    return attempts, held


class GraspGymEnv(gym.Env):
    """One bin of `Grasp` as a standard ``gymnasium.Env`` (numpy observations), ``taskrl/Grasp-v0``.

    Args:
        render_mode: None or ``rgb_array`` (the camera picture).
        **settings: fields of `GraspSettings` (``objects="held_out"``, ``image_size=84``, ...).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, render_mode: str | None = None, **settings: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self._env = Grasp(GraspSettings(**settings), num_envs=1)
        self.observation_space = self._env.single_observation_space
        self.action_space = self._env.single_action_space

    @staticmethod
    def _numpy(obs: Obs) -> dict[str, np.ndarray]:
        return {k: v[0].cpu().numpy().copy() for k, v in obs.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return self._numpy(self._env.reset(seed=int(self.np_random.integers(2**62)))), {}

    def step(self, action):
        _, reward, terminated, truncated, info = self._env.step(torch.as_tensor(np.asarray(action, dtype=np.float32))[None])
        extra = {"is_success": bool(info["is_success"][0]), "detected": bool(info["detected"][0])}
        return self._numpy(info["final_obs"]), float(reward[0]), bool(terminated[0]), bool(truncated[0]), extra

    def render(self):
        return self._env.render_rgb(0) if self.render_mode == "rgb_array" else None


def _make_grasp(settings: GraspSettings, request: EnvRequest) -> Grasp:
    return Grasp(settings, num_envs=request.copies, seed=request.seed, device=request.device)


FAMILY = EnvFamily(
    name="grasp",
    description="QT-Opt's bin from above: grasp one of several objects from a 64x64 camera picture (native torch)",
    section="grasp",
    settings=GraspSettings,
    make=_make_grasp,
    kind="plain",
    actions="box",
    images=True,
    scripted=True,
    held_out=lambda s: dataclasses.replace(s, objects="held_out"),
    video_env=lambda s: gym.make("taskrl/Grasp-v0", render_mode="rgb_array", **dataclasses.asdict(s)),
)
