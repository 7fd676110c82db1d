"""What every env family with a camera shares in its settings section: `CameraSettings`, validated in one place."""

from __future__ import annotations

import dataclasses

from taskrl.errors import require

__all__ = ["CameraSettings", "IMAGE_SIZES"]

#: the picture sides, in pixels, a camera may render (one range for every family)
IMAGE_SIZES = (16, 512)


@dataclasses.dataclass
class CameraSettings:
    """The camera of a family that renders pictures: a family's settings class derives from it (and may change
    the default size), and its ``validate()`` calls this one.

    Attributes:
        image_size: the side of the camera's square pictures in pixels (16-512); the observation's ``image``, and its
            ``goal_image`` where the env gives goals as pictures.
        shift: the random shift of every picture a learner trains on (DrQ's augmentation; BC-Z's random crop): padded
            by this many pixels, replicating the border, and cropped back at a random offset (a scene and its goal
            picture move together); 0: none; -1: the algorithm's own (4 for SAC and QT-Opt, as DrQ; 2 for behaviour
            cloning). Acting and evaluation see the pictures unshifted.
        shift_coordinates: move the positions the state vector gives in the picture's frame with the shifted
            picture (the grasp bin's gripper x, y: an env that declares ``picture_coordinates``), so that the state
            and the picture agree about where the gripper is; off: the picture moves, the state does not.
    """

    image_size: int = 64
    shift: int = -1
    shift_coordinates: bool = False

    def validate(self) -> None:
        low, high = IMAGE_SIZES
        require(low <= self.image_size <= high, "image_size", f"must be in {low}..{high} pixels (got {self.image_size})")
        half = self.image_size // 2
        require(
            -1 <= self.shift <= half,
            "shift",
            f"must be -1 (the algorithm's own), 0 (none) or up to half the picture, {half} pixels (got {self.shift})",
        )
