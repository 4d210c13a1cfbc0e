"""What every frame source hands the pipeline: frames to load, one at a time.

A source (a frame folder, a data set, a bag, a camera) is any iterable of ``FrameLoader``. The
loader names the frame before it is read, so a frame that cannot be read becomes a one-line
problem in the run ("ORIGIN: what is wrong") instead of stopping it, and reading happens where
the pipeline times it (and, with ``--overlap``, on the thread that prepares the next frame).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from a3d.runtime.structures.frame import Frame


@dataclass(frozen=True)
class FrameLoader:
    """One frame of a source, not read yet.

    ``origin`` is what a problem with the frame is reported against (its colour file, a bag and a
    time stamp, a camera); ``files`` the files it is read from, for messages that already name
    one of them; ``load`` reads and validates it (InputError "PATH: problem" when it cannot).
    """

    name: str
    origin: str
    load: Callable[[], Frame]
    files: tuple[str, ...] = field(default_factory=tuple)


def frame_loader(frame: Frame) -> FrameLoader:
    """A loader for a frame already in memory (arrays from the Python API, a camera's frame)."""
    return FrameLoader(frame.name, frame.origin or frame.name, lambda: frame)
