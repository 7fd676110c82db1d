"""Picture encoders (registered by name: ``conv``, ``resnet``, ``keypoints`` and the user's own) and the image
augmentation of the update.

An image observation reaches a network as the replay stores it, uint8 ``[B, H, W, C]`` (0-255) beside the state
vector ([`ObservationInput`][taskrl.agents.parts.ObservationInput] gives both as a
[`PictureState`][taskrl.types.PictureState]; no picture is flattened into the vector); `ImageStateInput`
encodes the pictures once per state with a conv stack or a small ResNet, and hands ``[vector, image features]`` on;
`GlimpseInput` adds the features of the picture around a gripper, turned into the jaws' frame. `random_shift` is DrQ's augmentation: pad by replicating the
border, crop back at a random offset drawn per observation (a scene and its goal picture move together).
"""

from taskrl.encoders.conv import conv_stack
from taskrl.encoders.glimpse import GlimpseInput
from taskrl.encoders.keypoints import SpatialSoftmax, keypoint_stack
from taskrl.encoders.registry import PICTURE_ENCODERS, picture_encoder, register_picture_encoder
from taskrl.encoders.resnet import small_resnet
from taskrl.encoders.shift import (
    BC_SHIFT,
    DRQ_SHIFT,
    PICTURE_KEYS,
    PictureCoordinate,
    picture_values,
    random_shift,
    random_shift_moves,
    shift_pictures,
)
from taskrl.encoders.spec import PictureEncoder
from taskrl.encoders.state_input import FiLMPictureEncoder, ImageStateInput, stacked_channels

__all__ = [
    "BC_SHIFT",
    "DRQ_SHIFT",
    "PICTURE_ENCODERS",
    "PICTURE_KEYS",
    "FiLMPictureEncoder",
    "GlimpseInput",
    "ImageStateInput",
    "PictureCoordinate",
    "PictureEncoder",
    "SpatialSoftmax",
    "conv_stack",
    "keypoint_stack",
    "picture_encoder",
    "picture_values",
    "random_shift",
    "random_shift_moves",
    "register_picture_encoder",
    "shift_pictures",
    "small_resnet",
    "stacked_channels",
]
