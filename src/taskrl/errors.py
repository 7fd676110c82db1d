"""The one error a bad setting raises, wherever it is checked: `ConfigError`.

Every config section checks itself (``section.validate()``) with `require`, so a rule is
written once and reads the same from the command line (one line, exit code 2) and from Python.
"""

from __future__ import annotations

__all__ = ["ConfigError", "one_of", "reason", "require"]


class ConfigError(ValueError):
    """A bad configuration value; ``field`` names the offending setting, ``message`` the allowed values."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message

    def __reduce__(self) -> tuple:
        return ConfigError, (self.field, self.message)  # whole across processes (a Ray role's error)


def require(ok: bool, field: str, message: str) -> None:
    """Raise `ConfigError` for ``field`` with ``message`` unless ``ok``."""
    if not ok:
        raise ConfigError(field, message)


def one_of(value: object, allowed: tuple, field: str, what: str = "value") -> None:
    """``value`` must be one of ``allowed``; the error lists them."""
    require(value in allowed, field, f"unknown {what} {value!r}; allowed: {', '.join(map(str, allowed))}")


def reason(error: BaseException, limit: int = 120) -> str:
    """An exception's first line, cut to ``limit`` characters (its type where it says nothing): what a
    one-line message quotes of a library's error."""
    text = str(error).strip()
    return text.splitlines()[0][:limit] if text else type(error).__name__
