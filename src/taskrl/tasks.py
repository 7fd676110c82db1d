"""Tasks and task sets: what a multi-task run trains on.

A :class:`TaskSpec` is one task: a version-free ``name`` (``reach``, ``pick-place``,
``top-left``), a one-sentence human-written ``description`` (the metadata that language
conditioning, e.g. CARE, embeds) and its ``index`` in the task set (the integer that
observations carry under the ``task`` key). A :class:`TaskSet` is the ordered list a run trains
on; ``TaskSet.from_pairs([(name, description), ...])`` numbers the tasks in order.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

__all__ = ["TaskSet", "TaskSpec"]


@dataclass(frozen=True)
class TaskSpec:
    """One task: ``name`` (version-free), ``description`` (a sentence), ``index`` (position in its set)."""

    name: str
    description: str
    index: int

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"TaskSpec.name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.description, str) or not self.description.strip():
            raise ValueError(f"TaskSpec.description of {self.name!r} must be a non-empty sentence, got {self.description!r}")
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 0:
            raise ValueError(f"TaskSpec.index of {self.name!r} must be an integer >= 0, got {self.index!r}")


class TaskSet(Sequence[TaskSpec]):
    """An ordered, immutable collection of tasks; task ``i`` has ``index == i``.

    ``task_set[i]`` is the i-th :class:`TaskSpec`, ``task_set["reach"]`` (or
    :meth:`get`) looks a task up by name and raises a ``KeyError`` listing the allowed names.
    """

    def __init__(self, tasks: Iterable[TaskSpec]) -> None:
        tasks = tuple(tasks)
        if not tasks:
            raise ValueError("a TaskSet needs at least one task")
        for i, task in enumerate(tasks):
            if not isinstance(task, TaskSpec):
                raise TypeError(f"TaskSet entries must be TaskSpec, got {type(task).__name__} at position {i}")
            if task.index != i:
                raise ValueError(f"task {task.name!r} is at position {i} but has index {task.index}; indices must be 0..n-1 in order")
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
            raise TypeError("TaskSet does not support slicing (indices would no longer match positions); use .names or list(task_set)")
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
        """The index of the task called ``name`` (same error as :meth:`get`)."""
        return self.get(name).index

    def __eq__(self, other: object) -> bool:
        return isinstance(other, TaskSet) and self._tasks == other._tasks

    def __hash__(self) -> int:
        return hash(self._tasks)

    def __repr__(self) -> str:
        return f"TaskSet({self.names})"
