"""What a Ray run does, decided on the driver before any worker starts (no Ray here).

Workers each hold a copy of the source and read the frames they are given by position, so only
sources whose frames can be listed and read independently, in any order and by any process,
can be spread: a frame folder, TUM, SUN RGB-D, 7-Scenes. A bag is read front to back through one
reader and a camera's frames exist once, in one process: those are refused in one line.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field

from a3d.runtime.errors import InputError
from a3d.runtime.selection import frames_to_do
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.registry import claiming_kind
from a3d.runtime.sources.wording import option

INDEPENDENT_KINDS = ("a3d", "7scenes", "tum", "sunrgbd")
"""The source kinds (a3d.runtime.sources.registry) whose frames each worker can list and read."""
_WHY_NOT = {
    "bag": "a bag is read front to back through one reader",
    "realsense": "a RealSense camera (or the SDK's playback) streams its frames once, to one process",
}


def check_independent(spec: str | os.PathLike, kind: str | None = None) -> None:
    """InputError naming SOURCE unless its kind (``kind``, else the one that claims it) is one of
    ``INDEPENDENT_KINDS``; a SOURCE no kind claims is left to ``open_source``'s own error."""
    name = kind or claiming_kind(spec)
    if name is None or name in INDEPENDENT_KINDS:
        return
    why = _WHY_NOT.get(name, f"a {name} source is not known to allow that")
    raise InputError(
        f"{os.fspath(spec)}: {option('ray')} needs frames that every worker can list and read on its own "
        f"(a frame folder, TUM, SUN RGB-D, 7-Scenes), and {why}; run it without {option('ray')}"
    )


@dataclass(frozen=True)
class Listing:
    """The frames to do, in source order (``positions`` in the source, ``names``), and ``index``,
    the position of every frame listed (done ones too): the order the output is merged in."""

    positions: list[int] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    index: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.positions)


def list_frames(
    source: Iterable[FrameLoader], done: set[str], shard: tuple[int, int] = (0, 1), limit: int | None = None
) -> Listing:
    """The frames a3d-run would do (a3d.runtime.selection.frames_to_do), listed without reading any."""
    listing = Listing()
    for loader in frames_to_do(source, done, listing.index, shard, limit):
        listing.positions.append(listing.index[loader.name])
        listing.names.append(loader.name)
    return listing
