"""Checkpoints that cannot execute code when loaded: tensors in safetensors, the rest in JSON.

A nested state (dicts, lists, numbers, strings, tensors; e.g. an optimizer's ``state_dict``) is
split into a flat ``{path: tensor}`` map and a JSON skeleton that references the tensors by path.
Each checkpoint is written to a folder of its own (a new name every time, even for the same
step), its files fsync'd, and then published by atomically replacing the ``latest`` pointer; the
folder ``latest`` names is never deleted. A run killed at any moment, mid-write included, keeps
its previous checkpoint intact. Any defect of a checkpoint (missing, truncated, foreign or
pickled files, a pointer outside the directory) is one `ConfigError` line.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from taskrl.errors import ConfigError, reason
from taskrl.rundir import atomic_write_text, fsync_dir

_TENSOR, _ITEMS = "__tensor__", "__items__"


def flatten_state(tree: Any, prefix: str = "", copy: bool = True) -> tuple[dict[str, torch.Tensor], Any]:
    """Split ``tree`` into ``(tensors, skeleton)``; non-string dict keys are kept exactly.

    ``copy=False`` keeps contiguous CPU tensors that start their storage (all of it or a prefix) as they are (no copy
    of a large replay),
    for a caller that writes them out at once: the result then aliases the live state.
    """
    tensors: dict[str, torch.Tensor] = {}

    def walk(node: Any, path: str) -> Any:
        if isinstance(node, torch.Tensor):
            tensor = node.detach()
            prefix = tensor.storage_offset() == 0  # the whole storage, or its first rows (a replay's written ones)
            if copy or tensor.is_cuda or not tensor.is_contiguous() or not prefix:
                tensor = tensor.cpu().contiguous().clone()  # a view or a device tensor: its own copy
            tensors[path] = tensor
            return {_TENSOR: path}
        if isinstance(node, dict):
            if all(isinstance(k, str) for k in node):
                return {k: walk(v, f"{path}.{k}") for k, v in node.items()}
            return {_ITEMS: [[k, walk(v, f"{path}.{k}")] for k, v in node.items()]}
        if isinstance(node, (list, tuple)):
            return [walk(v, f"{path}.{i}") for i, v in enumerate(node)]
        if node is None or isinstance(node, (bool, int, float, str)):
            return node
        raise TypeError(f"cannot checkpoint a value of type {type(node).__name__} at {path or 'root'}")

    return tensors, walk(tree, prefix)


def unflatten_state(tensors: dict[str, torch.Tensor], skeleton: Any) -> Any:
    def walk(node: Any) -> Any:
        if isinstance(node, dict):
            if _TENSOR in node:
                return tensors[node[_TENSOR]]
            if _ITEMS in node:
                return {k: walk(v) for k, v in node[_ITEMS]}
            return {k: walk(v) for k, v in node.items()}
        if isinstance(node, list):
            return [walk(v) for v in node]
        return node

    return walk(skeleton)


_NAME = re.compile(r"step_\d{12}(\.\d+)?")


def _folder_name(directory: Path, step: int) -> str:
    """``step_<step>``, or ``step_<step>.<n>`` if that exists (a stop checkpoint at a step already saved)."""
    name, n = f"step_{step:012d}", 0
    while (directory / name).exists():
        n += 1
        name = f"step_{step:012d}.{n}"
    return name


def _order(name: str) -> tuple[int, int]:
    step, _, n = name[len("step_") :].partition(".")
    return int(step), int(n or 0)


def save_checkpoint(directory: Path, parts: dict[str, Any], step: int, keep: int = 2) -> Path:
    """Write each named part of a state to ``directory/step_<step>/<part>.{safetensors,json}``
    and then point ``directory/latest`` at that folder; keep the ``keep`` newest folders.

    Parts load independently (an agent is loaded without reading the replay buffer).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    name = _folder_name(directory, step)
    target, staging = directory / name, directory / f".{name}.partial"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    for part, state in parts.items():
        tensors, skeleton = flatten_state(state, copy=False)  # written at once: no copy of the replay
        save_file(tensors, str(staging / f"{part}.safetensors"))
        (staging / f"{part}.json").write_text(json.dumps(skeleton))
    for file in staging.iterdir():  # on disk before anything points at them
        with open(file, "rb") as f:
            os.fsync(f.fileno())
    os.replace(staging, target)
    fsync_dir(directory)
    atomic_write_text(directory / "latest", name + "\n")
    folders = sorted((p.name for p in directory.glob("step_*") if _NAME.fullmatch(p.name)), key=_order)
    for old in folders[:-keep]:
        if old != name:
            shutil.rmtree(directory / old, ignore_errors=True)
    for partial in directory.glob(".step_*.partial"):  # left by a kill during an earlier write
        shutil.rmtree(partial, ignore_errors=True)
    return target


def latest_checkpoint(directory: Path) -> Path:
    """The folder ``directory/latest`` points to (always a ``step_*`` folder inside ``directory``)."""
    pointer = Path(directory) / "latest"
    if not pointer.exists():
        raise FileNotFoundError(f"no checkpoint in {directory} (missing 'latest')")
    name = pointer.read_text().strip()
    if not _NAME.fullmatch(name):
        raise ConfigError("checkpoint", f"{pointer} names {name[:80]!r}, not a checkpoint folder of this run")
    folder = Path(directory) / name
    if not folder.is_dir():
        raise ConfigError("checkpoint", f"{pointer} names {name}, which does not exist")
    return folder


def checkpoint_step(folder: Path) -> int:
    """The env step of a checkpoint folder (``step_000000001000.1`` -> 1000)."""
    return _order(Path(folder).name)[0]


def checkpoint_at(directory: Path, step: int | None = None) -> Path:
    """The latest checkpoint folder, or the newest one of env step ``step``."""
    if step is None:
        return latest_checkpoint(directory)
    folders = sorted((p.name for p in Path(directory).glob(f"step_{step:012d}*") if _NAME.fullmatch(p.name)), key=_order)
    if not folders:
        have = sorted(checkpoint_step(p) for p in Path(directory).glob("step_*") if _NAME.fullmatch(p.name))
        raise ConfigError("checkpoint", f"no checkpoint at step {step:,}; this run keeps: {', '.join(map(str, have)) or 'none'}")
    return Path(directory) / folders[-1]


def load_checkpoint(
    directory: Path, parts: tuple[str, ...], device: str | torch.device = "cpu", step: int | None = None
) -> dict[str, Any]:
    """Load the named parts of the latest checkpoint in ``directory`` (or of env step ``step``),
    tensors on ``device``.

    Absent parts (e.g. a replay that was not saved) are left out of the result. Only safetensors
    and JSON are read: nothing in a checkpoint can run code.
    """
    return read_checkpoint(checkpoint_at(directory, step), parts, device)


def read_checkpoint(folder: Path, parts: tuple[str, ...], device: str | torch.device = "cpu") -> dict[str, Any]:
    """Load the named parts of one checkpoint folder (see `load_checkpoint`)."""
    out = {}
    for part in parts:
        skeleton_file, tensor_file = folder / f"{part}.json", folder / f"{part}.safetensors"
        if not skeleton_file.exists():
            continue
        try:
            tensors = load_file(str(tensor_file), device=str(device))
            out[part] = unflatten_state(tensors, json.loads(skeleton_file.read_text()))
        except Exception as error:  # truncated, garbage, pickled or foreign files: one line, nothing run
            raise ConfigError(
                "checkpoint", f"{folder / part} is damaged or not a taskrl checkpoint ({reason(error, 160)})"
            ) from None
    return out
