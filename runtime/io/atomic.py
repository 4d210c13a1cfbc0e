"""Atomic file writes: a reader (or a run killed mid-write) sees the old file or the new one, never a
partial file.

The new content goes to a temporary file beside the target (``.NAME.tmp-PID-RANDOM``, opened like
any new file: mode 0666 less the umask, unlike mkstemp's 0600), which is then renamed over the
target. ``durable`` also fsyncs the file before the rename and the folder after it, so the new
file survives a power loss too (checkpoints); a killed writer leaves its temporary file behind,
which ``remove_stale_temporaries`` clears where a folder has a single writer.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def atomic_write(
    path: str | os.PathLike, write: Callable[[BinaryIO], object], *, durable: bool = False
) -> None:
    """Create or replace ``path`` with what ``write(file)`` writes into an open binary file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{_temporary_prefix(path)}{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        with open(tmp, "xb") as f:
            write(f)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync_dir(path.parent)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, durable: bool = False) -> None:
    """Create or replace ``path`` with ``data``."""
    atomic_write(path, lambda f: f.write(data), durable=durable)


def remove_stale_temporaries(path: str | os.PathLike) -> None:
    """Delete the temporary files that killed writers of ``path`` left (only safe with one writer)."""
    path = Path(path)
    for stale in path.parent.glob(f"{_temporary_prefix(path)}*"):
        stale.unlink(missing_ok=True)


def _temporary_prefix(path: Path) -> str:
    return f".{path.name}.tmp-"


def _fsync_dir(folder: Path) -> None:
    """Make the rename itself durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
