"""The output of a Ray run: one part file per finished block, merged into the output at the end.

Blocks finish in any order, and a run over millions of frames must survive being stopped, so each
block's lines go to their own file as soon as it comes back, written atomically and named by the
source position of its first frame: ``.NAME.parts/000000001234.jsonl`` beside the output ``NAME``.
``--resume`` counts the frames of the output and of the parts; the end of the run merges both, in
source order, into the output (atomically: a reader sees the old file or the whole new one), then
deletes the parts. The lines are a3d-run's, untouched (a3d.runtime.io.detections_io.format_line).
"""

from __future__ import annotations

import heapq
import itertools
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write, atomic_write_bytes
from a3d.runtime.selection import completed_frames

POSITION_DIGITS = 12  # part names sort as their positions do, up to a trillion frames


class Parts:
    """The part files of one output (module docstring)."""

    def __init__(self, output: str | Path) -> None:
        self.output = Path(output)
        self.folder = self.output.with_name(f".{self.output.name}.parts")

    def files(self) -> list[Path]:
        """The part files in source order (their temporaries, ``.NAME.tmp-*``, left out)."""
        return sorted(self.folder.glob("*.jsonl")) if self.folder.is_dir() else []

    def frames(self) -> set[str]:
        """The frames the parts hold (each line checked as --resume checks the output)."""
        return set().union(*(completed_frames(path) for path in self.files()))

    def start(self, resume: bool) -> set[str]:
        """Before a run: with ``resume`` the frames the parts already hold; without, an empty output
        and no parts (as a3d-run starts), so that a later --resume counts only this run's frames.
        InputError naming the output when it cannot be written."""
        if resume:
            return self.frames()
        try:
            self.clear()
            self.output.parent.mkdir(parents=True, exist_ok=True)
            self.output.write_bytes(b"")
        except OSError as e:
            raise InputError(f"{self.output}: cannot write ({e.strerror or e})") from None
        return set()

    def write(self, lines: list[tuple[int, str]]) -> None:
        """One finished block's lines, (source position, line), as one part file (none for none)."""
        if not lines:
            return
        lines = sorted(lines)
        self.folder.mkdir(parents=True, exist_ok=True)
        data = "".join(f"{line}\n" for _, line in lines).encode("utf-8")
        atomic_write_bytes(self.folder / f"{lines[0][0]:0{POSITION_DIGITS}d}.jsonl", data, durable=True)

    def merge(self, index: dict[str, int]) -> None:
        """The output's lines and the parts' as one file in source order (``index``: frame name ->
        position; frames it does not know go last, in their order), then the parts deleted. A frame
        both hold (a plain a3d-run --resume in between) keeps the output's line."""
        parts = itertools.chain.from_iterable(_lines(path) for path in self.files())
        if not (self.output.is_file() and self.output.stat().st_size):
            ordered: Iterator[bytes] = parts  # the usual case: parts hold their frames in order already
        else:
            both = (_keyed(_lines(self.output), index), _keyed(parts, index))
            ordered = _first_of_each(heapq.merge(*both, key=lambda item: item[0]))  # stable: output first

        def write(f: BinaryIO) -> None:
            for line in ordered:
                f.write(line)

        atomic_write(self.output, write, durable=True)
        self.clear()

    def clear(self) -> None:
        if self.folder.exists():
            shutil.rmtree(self.folder)


def _lines(path: Path) -> Iterator[bytes]:
    """The file's non-blank lines, each with its newline."""
    with open(path, "rb") as f:
        for line in f:
            if line.strip():
                yield line if line.endswith(b"\n") else line + b"\n"


def _keyed(lines: Iterator[bytes], index: dict[str, int]) -> Iterator[tuple[int, str, bytes]]:
    """(position, frame name, line) of each line."""
    for line in lines:
        name = json.loads(line)["frame"]
        yield index.get(name, len(index)), name, line


def _first_of_each(items: Iterator[tuple[int, str, bytes]]) -> Iterator[bytes]:
    """The lines, each frame's first only."""
    seen: set[str] = set()
    for _, name, line in items:
        if name not in seen:
            seen.add(name)
            yield line
