"""Keeping run directories whole: what may become one, one process at a time, files replaced atomically.

- `check_new_run_dir`: ``--out`` must be a new or empty directory (a run is continued with
  ``--resume``; any other directory is left untouched);
- `RunLock`: one process per run directory (an advisory ``flock`` the OS releases when the
  process dies, so a killed run never leaves a stale lock);
- `atomic_write_text`: temp file, fsync, rename: a reader sees the old file or the new one.
"""

from __future__ import annotations

import os
from pathlib import Path

from taskrl.errors import ConfigError

__all__ = ["RunLock", "atomic_write_text", "check_new_run_dir", "fsync_dir"]

LOCK_NAME = ".lock"


def check_new_run_dir(out: str | os.PathLike) -> Path:
    """The path of a run to start at ``out``; a `ConfigError` on ``out`` when it is not new or empty."""
    if str(out).strip() == "":
        raise ConfigError("out", "must name a directory (got an empty string)")
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ConfigError("out", f"{path} is a file, not a directory; choose a new --out")
    if path.is_dir():
        entries = sorted(p.name for p in path.iterdir() if p.name != LOCK_NAME)
        if "checkpoints" in entries or "config.json" in entries:
            raise ConfigError("out", f"{path} already holds a run; pass --resume {path} to continue it")
        if entries:
            shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
            raise ConfigError(
                "out", f"{path} is not empty ({shown}) and is not a run directory: choose a new --out (nothing in it was touched)"
            )
    return path


class RunLock:
    """Held while a process trains in ``run_dir``; a second process gets a `ConfigError` on ``field``.

    Args:
        run_dir: the run directory (must exist).
        field: the setting named in the error (``out`` for a new run, ``resume`` for a resumed one).
    """

    def __init__(self, run_dir: Path, field: str = "out") -> None:
        self.path, self.field, self._file = Path(run_dir) / LOCK_NAME, field, None

    def __enter__(self) -> RunLock:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - no advisory locks on this platform
            return self
        handle = open(self.path, "a+")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip() or "?"
            handle.close()
            raise ConfigError(
                self.field,
                f"{self.path.parent} is in use by another taskrl process (pid {holder}); wait for it, or stop it first",
            ) from None
        handle.seek(0), handle.truncate(), handle.write(f"{os.getpid()}\n"), handle.flush()
        self._file = handle
        return self

    def __exit__(self, *exc: object) -> None:
        if self._file is not None:
            self._file.close()  # closing releases the lock
            self._file = None


def fsync_dir(path: Path) -> None:
    """Make a rename inside ``path`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # pragma: no cover
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Replace ``path`` with ``text``: written to a temp file, fsync'd, renamed over it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)
