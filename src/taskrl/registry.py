"""One registry type for the named specs runs choose from (env families, algorithms)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Generic, TypeVar

from taskrl.errors import ConfigError

__all__ = ["Registry"]

T = TypeVar("T")


class Registry(dict[str, T], Generic[T]):
    """``name -> spec`` in registration order; every spec has a ``name``.

    Args:
        setting: the setting that names an entry (``env``, ``algo``), for errors.
        specs: the built-in entries.
        hint: added to the unknown-name error (e.g. where else a value could go).
    """

    def __init__(self, setting: str, specs: Iterable[T] = (), hint: str = "") -> None:
        super().__init__()
        self.setting, self.hint = setting, hint
        for spec in specs:
            self.register(spec)

    def register(self, spec: T, replace: bool = False) -> T:
        """Add ``spec`` under ``spec.name``; a name already taken needs ``replace=True``."""
        name = spec.name  # type: ignore[attr-defined]
        if name in self and not replace:
            raise ValueError(f"a {self.setting} named {name!r} is already registered (pass replace=True)")
        self[name] = spec
        return spec

    def lookup(self, name: str) -> T:
        """The spec called ``name``; a `ConfigError` on the setting listing the registered names."""
        if name not in self:
            raise ConfigError(self.setting, f"unknown {self.setting} {name!r}; allowed: {', '.join(self)}{self.hint}")
        return self[name]
