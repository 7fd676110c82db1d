"""What a setting's value may be: the one type check of every setting however it arrives, and which
fields of a section differ from their defaults."""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from typing import Any

from taskrl.errors import one_of, require

__all__ = ["changed_fields", "check_device", "checked_value"]


def changed_fields(section: Any) -> dict[str, Any]:
    """Fields of ``section`` (a settings dataclass) that differ from its class's defaults."""
    default = type(section)()
    return {
        f.name: getattr(section, f.name)
        for f in dataclasses.fields(section)
        if getattr(section, f.name) != getattr(default, f.name)
    }


def checked_value(name: str, value: Any, tp: Any) -> Any:
    """``value`` as a setting of type ``tp``, or a `ConfigError` naming ``name`` and what it must be.

    The one type check of every setting, however it arrives (a flag, a keyword of ``taskrl.train``,
    a saved ``config.json``): integers (an integral float such as ``1e6`` is accepted), finite
    numbers, booleans, strings, one of a ``Literal``'s values, lists of whole numbers or (``tuple[float, ...]``) of
    finite numbers.
    """
    origin = typing.get_origin(tp)
    if tp is bool:
        require(isinstance(value, bool), name, f"must be true or false (got {value!r})")
        return value
    if tp is int:
        integral = isinstance(value, float) and math.isfinite(value) and value.is_integer()
        require(
            (isinstance(value, int) and not isinstance(value, bool)) or integral, name, f"must be a whole number (got {value!r})"
        )
        return int(value)
    if tp is float:
        require(isinstance(value, (int, float)) and not isinstance(value, bool), name, f"must be a number (got {value!r})")
        require(math.isfinite(value), name, f"must be a finite number (got {value!r})")
        return float(value)
    if tp is str:
        require(isinstance(value, str), name, f"must be a string (got {value!r})")
        return value
    if origin is typing.Literal:
        one_of(value, typing.get_args(tp), name, "value")
        return value
    if origin is tuple and typing.get_args(tp)[:1] == (float,):
        ok = isinstance(value, (list, tuple)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
        )
        require(ok, name, f"must be a list of numbers, e.g. [0, 0, -1, 0] (got {value!r})")
        return tuple(float(v) for v in value)
    if origin is tuple:
        ok = isinstance(value, (list, tuple)) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        require(ok, name, f"must be a list of whole numbers, e.g. [256, 256] (got {value!r})")
        return tuple(value)
    return value  # a section (checked field by field) or a free-form value


def check_device(name: str, field: str = "device") -> None:
    """``cpu``, ``cuda``, ``cuda:N`` or ``auto``; anything else is a `ConfigError` on ``field``."""
    require(
        isinstance(name, str) and re.fullmatch(r"cpu|auto|cuda(:\d+)?", name) is not None,
        field,
        f"unknown device {name!r}; allowed: cpu, cuda, cuda:N, auto",
    )
