"""One registry type for the named specs runs choose from (env families, algorithms, sharing strategies,
picture encoders, run modes).

Built-in entries are declared by where they live (`Declared`) and imported on first use: reading a config
that names ``bitflip`` and ``dqn`` imports those two files, not Meta-World's or the grasping env's.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Iterable, Iterator, MutableMapping
from typing import Any, Generic, TypeVar

from taskrl.errors import ConfigError

__all__ = ["Declared", "Registry"]

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Declared:
    """A built-in entry by name and place: ``module``'s ``attribute``, a spec called ``name`` or a sequence of
    specs holding one (a file that declares several families), imported when the entry is first read."""

    name: str
    module: str
    attribute: str

    def load(self) -> Any:
        value = getattr(importlib.import_module(self.module), self.attribute)
        found = [value] if hasattr(value, "name") else [spec for spec in value if spec.name == self.name]
        if len(found) != 1 or found[0].name != self.name:  # the declaration and the file disagree: a bug here
            raise LookupError(f"{self.module}.{self.attribute} declares no entry called {self.name!r}")
        return found[0]


class Registry(MutableMapping[str, T], Generic[T]):
    """``name -> spec`` in registration order; every spec has a ``name``.

    Args:
        setting: the setting that names an entry (``env``, ``algo``), for errors.
        specs: the built-in entries: specs, or `Declared` places imported on first use.
        hint: added to the unknown-name error (e.g. where else a value could go).
    """

    def __init__(self, setting: str, specs: Iterable[T | Declared] = (), hint: str = "") -> None:
        self.setting, self.hint = setting, hint
        self._entries: dict[str, T | Declared] = {}
        for spec in specs:
            self.register(spec)  # type: ignore[arg-type]

    def register(self, spec: T, replace: bool = False) -> T:
        """Add ``spec`` under ``spec.name``; a name already taken needs ``replace=True``."""
        name = spec.name  # type: ignore[attr-defined]
        if name in self._entries and not replace:
            raise ValueError(f"a {self.setting} named {name!r} is already registered (pass replace=True)")
        self._entries[name] = spec
        return spec

    def lookup(self, name: str) -> T:
        """The spec called ``name``; a `ConfigError` on the setting listing the registered names."""
        if name not in self._entries:
            raise ConfigError(self.setting, f"unknown {self.setting} {name!r}; allowed: {', '.join(self)}{self.hint}")
        return self[name]

    def __getitem__(self, name: str) -> T:
        entry = self._entries[name]
        if isinstance(entry, Declared):
            entry = self._entries[name] = entry.load()
        return entry  # type: ignore[return-value]

    def __setitem__(self, name: str, spec: T) -> None:
        self._entries[name] = spec

    def __delitem__(self, name: str) -> None:
        del self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries
