"""What a preset is: a named, documented starting point for ``taskrl train PRESET``."""

from __future__ import annotations

import dataclasses

__all__ = ["Preset"]


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named starting point.

    Attributes:
        description: one line for ``taskrl presets``.
        overrides: the settings it changes from the defaults, by name (as ``taskrl.train(**overrides)`` takes them).
    """

    description: str
    overrides: dict
