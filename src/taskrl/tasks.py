"""Tasks and task sets: what a multi-task run trains on.

A `TaskSpec` is one task: a version-free ``name`` (``reach``, ``pick-place``,
``top-left``), a one-sentence human-written ``description`` (the metadata that language
conditioning, e.g. CARE, embeds) and its ``index`` in the task set (the integer that
observations carry under the ``task`` key). A `TaskSet` is the ordered list a run trains
on; ``TaskSet.from_pairs([(name, description), ...])`` numbers the tasks in order.

A task may also say where it runs (``env``): a gymnasium id (with ``env_kwargs``) or a zero-argument
factory of a ``gymnasium.Env``; a task without one is a Meta-World task named by ``name``. A task
file (JSON or YAML) lists the same, ``TaskSet.from_file(path)`` reads it::

    tasks:
      - {name: slide-left, description: Slide the block to the left end., env: my/Slider-v0, env_kwargs: {target: -0.8}}
      - {name: slide-right, description: Slide the block to the right end., env: my/Slider-v0, env_kwargs: {target: 0.8}}
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from taskrl.files import read_data_file

__all__ = ["TaskSet", "TaskSpec"]

_ENTRY_KEYS = ("name", "description", "env", "env_kwargs")


@dataclass(frozen=True)
class TaskSpec:
    """One task: ``name`` (version-free), ``description`` (a sentence), ``index`` (position in its set),
    and optionally where it runs: ``env`` (a gymnasium id or a zero-argument factory of a
    ``gymnasium.Env``) with ``env_kwargs`` for ``gymnasium.make``."""

    name: str
    description: str
    index: int
    env: str | Callable[[], Any] | None = field(default=None, compare=False)
    env_kwargs: dict[str, Any] | None = field(default=None, compare=False, hash=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"TaskSpec.name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.description, str) or not self.description.strip():
            raise ValueError(f"TaskSpec.description of {self.name!r} must be a non-empty sentence, got {self.description!r}")
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 0:
            raise ValueError(f"TaskSpec.index of {self.name!r} must be an integer >= 0, got {self.index!r}")
        if self.env is not None and not (isinstance(self.env, str) and self.env) and not callable(self.env):
            raise ValueError(
                f"TaskSpec.env of {self.name!r} must be a gymnasium id or a factory of a gymnasium.Env, got {self.env!r}"
            )
        if self.env_kwargs is not None and (not isinstance(self.env_kwargs, dict) or not isinstance(self.env, str)):
            raise ValueError(f"TaskSpec.env_kwargs of {self.name!r} must be a dict, with env a gymnasium id")


class TaskSet(Sequence[TaskSpec]):
    """An ordered, immutable collection of tasks; task ``i`` has ``index == i``.

    ``task_set[i]`` is the i-th `TaskSpec`, ``task_set["reach"]`` (or
    `get`) looks a task up by name and raises a ``KeyError`` listing the allowed names.
    """

    def __init__(self, tasks: Iterable[TaskSpec]) -> None:
        tasks = tuple(tasks)
        if not tasks:
            raise ValueError("a TaskSet needs at least one task")
        for i, task in enumerate(tasks):
            if not isinstance(task, TaskSpec):
                raise TypeError(f"TaskSet entries must be TaskSpec, got {type(task).__name__} at position {i}")
            if task.index != i:
                raise ValueError(
                    f"task {task.name!r} is at position {i} but has index {task.index}; indices must be 0..n-1 in order"
                )
        names = [t.name for t in tasks]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"task names must be unique; repeated: {', '.join(duplicates)}")
        self._tasks = tasks
        self._by_name = {t.name: t for t in tasks}

    @classmethod
    def from_pairs(cls, pairs: Iterable[tuple[str, str]]) -> TaskSet:
        """A task set from ``(name, description)`` pairs, indexed in order."""
        return cls(TaskSpec(name, description, i) for i, (name, description) in enumerate(pairs))

    @classmethod
    def from_entries(cls, entries: Iterable[dict[str, Any]], where: str = "tasks") -> TaskSet:
        """A task set from dicts with ``name``, ``description`` and optionally ``env``, ``env_kwargs``."""
        tasks = []
        for i, entry in enumerate(entries):
            if not isinstance(entry, dict):
                raise ValueError(f"{where}: entry {i} must be a mapping with name and description, got {entry!r}")
            unknown = sorted(set(entry) - set(_ENTRY_KEYS))
            if unknown or "name" not in entry or "description" not in entry:
                raise ValueError(
                    f"{where}: entry {i} has keys {sorted(entry)}; allowed: {', '.join(_ENTRY_KEYS)} "
                    f"(name and description required)"
                )
            tasks.append(TaskSpec(entry["name"], entry["description"], i, entry.get("env"), entry.get("env_kwargs")))
        return cls(tasks)

    @classmethod
    def from_file(cls, path: str | Path) -> TaskSet:
        """Read a JSON or YAML task file: a list of tasks, or a mapping with a ``tasks`` list."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"task file {path} does not exist")
        data = read_data_file(path)
        if isinstance(data, dict):
            data = data.get("tasks")
        if not isinstance(data, list):
            raise ValueError(f"{path}: expected a list of tasks (or a mapping with a 'tasks' list)")
        return cls.from_entries(data, where=str(path))

    def to_entries(self, describe_factory: Callable[[Any], str] = repr) -> list[dict[str, Any]]:
        """JSON-able entries; a factory ``env`` is written as ``describe_factory(env)``."""
        out = []
        for t in self._tasks:
            entry: dict[str, Any] = {"name": t.name, "description": t.description}
            if t.env is not None:
                entry["env"] = t.env if isinstance(t.env, str) else describe_factory(t.env)
            if t.env_kwargs:
                entry["env_kwargs"] = dict(t.env_kwargs)
            out.append(entry)
        return out

    @property
    def names(self) -> list[str]:
        return [t.name for t in self._tasks]

    @property
    def descriptions(self) -> list[str]:
        return [t.description for t in self._tasks]

    def __len__(self) -> int:
        return len(self._tasks)

    def __iter__(self) -> Iterator[TaskSpec]:
        return iter(self._tasks)

    def __getitem__(self, key):  # type: ignore[override]
        if isinstance(key, str):
            return self.get(key)
        if isinstance(key, slice):
            raise TypeError(
                "TaskSet does not support slicing (indices would no longer match positions); use .names or list(task_set)"
            )
        return self._tasks[key]

    def __contains__(self, item: object) -> bool:
        if isinstance(item, str):
            return item in self._by_name
        return item in self._tasks

    def get(self, name: str) -> TaskSpec:
        """The task called ``name``; a ``KeyError`` naming the allowed names otherwise."""
        try:
            return self._by_name[name]
        except (KeyError, TypeError):
            raise KeyError(f"unknown task {name!r}; allowed names: {', '.join(self.names)}") from None

    def index(self, name: str) -> int:  # type: ignore[override]
        """The index of the task called ``name`` (same error as `get`)."""
        return self.get(name).index

    def __eq__(self, other: object) -> bool:
        return isinstance(other, TaskSet) and self._tasks == other._tasks

    def __hash__(self) -> int:
        return hash(self._tasks)

    def __repr__(self) -> str:
        return f"TaskSet({self.names})"
