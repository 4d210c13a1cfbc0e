"""Which frames of a source a run does: a shard of the first N, less those its output already has.

a3d-run's ``--shard K/N``, ``--max-frames N`` and ``--resume`` mean the same with or without
``--ray`` (a3d.runtime.scale), so both take the frames from here.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import parse_line
from a3d.runtime.sources.base import FrameLoader


def frames_to_do(
    source: Iterable[FrameLoader],
    done: set[str],
    index: dict[str, int],
    shard: tuple[int, int] = (0, 1),
    limit: int | None = None,
) -> Iterator[FrameLoader]:
    """The source's frames of this ``shard`` (K, N) among its first ``limit`` (all for None):
    positions K, K + N, ..., lazily, less those already done; ``index`` learns each frame's
    position as it goes (so a live source is never drained ahead of the run). The source's
    iterator is closed when this one is, so a camera is stopped however the run ends."""
    k, n = shard
    frames = iter(source)
    try:
        for position, loader in enumerate(itertools.islice(frames, limit)):
            index[loader.name] = position
            if position % n == k and loader.name not in done:
                yield loader
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()


def completed_frames(path: Path) -> set[str]:
    """Frames that already have a complete line in ``path`` (for --resume); empty if it does not exist.

    A partial last line (no newline: the run was killed while writing it) is cut off the file.
    Every complete line must be a valid detections line, else InputError: resuming appends to
    the file, so it must be one a3d-run wrote.
    """
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return set()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    end = data.rfind(b"\n") + 1
    names: set[str] = set()
    for number, raw in enumerate(data[:end].split(b"\n")[:-1], start=1):
        if not raw.strip():
            continue
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{path}:{number}: not UTF-8 text; not a detections file to resume") from None
        names.add(parse_line(text, f"{path}:{number}").frame)
    if end < len(data):
        os.truncate(path, end)
    return names
