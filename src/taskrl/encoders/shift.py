"""DrQ's random shift of pictures, and which observation keys hold pictures."""

from __future__ import annotations

import functools
import math

import torch

from taskrl.types import PictureCoordinate

__all__ = [
    "BC_SHIFT",
    "DRQ_SHIFT",
    "PICTURE_KEYS",
    "PictureCoordinate",
    "picture_values",
    "random_shift",
    "random_shift_moves",
    "shift_pictures",
]

#: pixels of shift of the RL agents' pictures when the camera does not set one: DrQ's pad of 4 (Kostrikov et al. 2020)
DRQ_SHIFT = 4
#: pixels of shift of behaviour cloning's pictures when the camera does not set one (BC-Z's random crop, at 32x32)
BC_SHIFT = 2

#: the observation keys that hold pictures, in the order they are stacked for the encoder (the scene, then its goal)
PICTURE_KEYS = ("image", "goal_image")


def random_shift_moves(
    images: torch.Tensor, pad: int, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """DrQ's random shift of ``[B, H, W, C]`` pictures: replicate-pad by ``pad`` and crop back at an offset
    drawn per picture (0 to ``2 * pad`` in each direction). Returns the shifted pictures (same dtype and shape) and
    ``[B, 2]``: how many pixels each picture's content moved (rows down, columns right; ``pad`` minus the offset)."""
    b, h, w, c = images.shape
    if pad <= 0:
        return images, torch.zeros(b, 2, dtype=torch.long, device=images.device)
    offset = torch.randint(0, 2 * pad + 1, (b, 2), generator=generator, device=images.device)
    # the padded picture is never built: a pixel of the crop reads the source pixel its row and column clamp to
    # (what replicate padding holds there), one gather of whole pixels in the pictures' own dtype and layout
    arange = functools.partial(torch.arange, device=images.device)
    rows = (offset[:, 0:1] - pad + arange(h)).clamp(0, h - 1)  # [B, H] source row of each crop row
    cols = (offset[:, 1:2] - pad + arange(w)).clamp(0, w - 1)  # [B, W]
    pixel = (arange(b)[:, None, None] * h + rows[:, :, None]) * w + cols[:, None, :]  # [B, H, W] flat source pixel
    shifted = images.reshape(b * h * w, c).index_select(0, pixel.reshape(-1)).reshape(b, h, w, c)
    return shifted, pad - offset


def random_shift(images: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """`random_shift_moves`'s shifted pictures alone."""
    return random_shift_moves(images, pad, generator)[0]


def shift_pictures(
    obs: dict[str, torch.Tensor],
    pad: int,
    generator: torch.Generator | None = None,
    coordinates: tuple[PictureCoordinate, ...] = (),
) -> dict[str, torch.Tensor]:
    """``obs`` with its pictures (`PICTURE_KEYS`) shifted by `random_shift`: one offset per row,
    shared by the row's pictures, since a scene and its goal picture come from one camera and the policy
    reads where the scene differs from the goal (independent offsets would move that difference by up to
    ``2 * pad`` pixels). ``coordinates``: vector entries that are positions in the picture's frame, moved with it
    (a gripper's position then stays where the picture shows it)."""
    keys = [k for k in PICTURE_KEYS if k in obs]
    if not keys:
        return obs
    channels = [obs[k].shape[-1] for k in keys]
    shifted, moves = random_shift_moves(torch.cat([obs[k] for k in keys], dim=-1), pad, generator)
    out = {**obs, **dict(zip(keys, shifted.split(channels, dim=-1)))}
    for key in {c.key for c in coordinates}:
        value = out[key].clone()
        for c in coordinates:
            if c.key == key:
                value[:, c.index] += moves[:, 0 if c.axis == "row" else 1].to(value.dtype) * c.per_pixel
        out[key] = value
    return out


def picture_values(shape: tuple[int, ...]) -> int:
    """The values one observation's pictures of ``shape`` hold (``H*W*C``, or ``K*H*W*C``)."""
    return int(math.prod(shape))
