"""The picture encoders a run can use, by name: one [`PictureEncoder`][taskrl.encoders.spec.PictureEncoder] each.

Each encoder's file declares its spec; adding one is that file plus one line in `BUILT_IN`, or
`register_picture_encoder` from a user's code (``--env-module``).
"""

from __future__ import annotations

from taskrl.encoders.conv import CONV
from taskrl.encoders.keypoints import KEYPOINTS
from taskrl.encoders.resnet import RESNET
from taskrl.encoders.spec import PictureEncoder
from taskrl.errors import ConfigError
from taskrl.registry import Registry

__all__ = ["PICTURE_ENCODERS", "picture_encoder", "register_picture_encoder"]

BUILT_IN: tuple[PictureEncoder, ...] = (CONV, RESNET, KEYPOINTS)

#: name -> spec, in registration order.
PICTURE_ENCODERS: Registry[PictureEncoder] = Registry("encoder", BUILT_IN)


def register_picture_encoder(spec: PictureEncoder, replace: bool = False) -> PictureEncoder:
    """Make ``spec`` available as ``--encoder spec.name`` to every agent that reads pictures."""
    return PICTURE_ENCODERS.register(spec, replace)


def picture_encoder(name: str, film: bool = False, late_input: bool = False) -> PictureEncoder:
    """The spec of ``name``; a `ConfigError` on ``encoder`` listing the registered names otherwise (with ``film``:
    those behaviour cloning can FiLM-modulate; with ``late_input``: those that declare a layer for a late input)."""
    spec = PICTURE_ENCODERS.lookup(name)
    if film and spec.film_blocks is None:
        fitting = ", ".join(e.name for e in PICTURE_ENCODERS.values() if e.film_blocks is not None)
        raise ConfigError("encoder", f"behaviour cloning FiLM-modulates every block; {name!r} has none; allowed: {fitting}")
    if late_input and spec.late_input is None:
        fitting = ", ".join(e.name for e in PICTURE_ENCODERS.values() if e.late_input is not None)
        raise ConfigError("encoder", f"fusion=conv adds the action to a feature map; {name!r} declares none; allowed: {fitting}")
    return spec
