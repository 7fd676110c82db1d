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
    """

    image_size: int = 64

    def validate(self) -> None:
        low, high = IMAGE_SIZES
        require(low <= self.image_size <= high, "image_size", f"must be in {low}..{high} pixels (got {self.image_size})")
