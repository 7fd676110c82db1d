"""Checkpoints that cannot execute code when loaded: tensors in safetensors, the rest in JSON.

A nested state (dicts, lists, numbers, strings, tensors; e.g. an optimizer's ``state_dict``) is
split into a flat ``{path: tensor}`` map and a JSON skeleton that references the tensors by path.
Each checkpoint is written to its own folder and then published by atomically replacing the
``latest`` pointer, so a run killed mid-write still has its previous checkpoint intact.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

_TENSOR, _ITEMS = "__tensor__", "__items__"


def flatten_state(tree: Any, prefix: str = "") -> tuple[dict[str, torch.Tensor], Any]:
    """Split ``tree`` into ``(tensors, skeleton)``; non-string dict keys are kept exactly."""
    tensors: dict[str, torch.Tensor] = {}

    def walk(node: Any, path: str) -> Any:
        if isinstance(node, torch.Tensor):
            tensors[path] = node.detach().cpu().contiguous().clone()
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


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def save_checkpoint(directory: Path, parts: dict[str, Any], step: int, keep: int = 2) -> Path:
    """Write each named part of a state to ``directory/step_<step>/<part>.{safetensors,json}``
    and then point ``directory/latest`` at that folder.

    Parts load independently (an agent is loaded without reading the replay buffer).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:012d}"
    target, staging = directory / name, directory / f".{name}.partial"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    for part, state in parts.items():
        tensors, skeleton = flatten_state(state)
        save_file(tensors, str(staging / f"{part}.safetensors"))
        (staging / f"{part}.json").write_text(json.dumps(skeleton))
    shutil.rmtree(target, ignore_errors=True)
    os.replace(staging, target)
    _atomic_write_text(directory / "latest", name + "\n")
    for old in sorted(directory.glob("step_*"))[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return target


def latest_checkpoint(directory: Path) -> Path:
    """The folder ``directory/latest`` points to."""
    pointer = Path(directory) / "latest"
    if not pointer.exists():
        raise FileNotFoundError(f"no checkpoint in {directory} (missing 'latest')")
    return Path(directory) / pointer.read_text().strip()


def load_checkpoint(directory: Path, parts: tuple[str, ...], device: str | torch.device = "cpu") -> dict[str, Any]:
    """Load the named parts of the latest checkpoint in ``directory`` (tensors on ``device``).

    Absent parts (e.g. a replay that was not saved) are left out of the result.
    """
    folder = latest_checkpoint(directory)
    out = {}
    for part in parts:
        if (folder / f"{part}.json").exists():
            tensors = load_file(str(folder / f"{part}.safetensors"), device=str(device))
            out[part] = unflatten_state(tensors, json.loads((folder / f"{part}.json").read_text()))
    return out
