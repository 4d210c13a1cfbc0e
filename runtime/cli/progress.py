"""a3d-run's progress on stderr: tqdm's bar on a terminal, a plain line every few seconds otherwise.

tqdm draws nothing when stderr is not a terminal (a log file, a CI job, ``2> run.log``), which
left a long run silent until its end. There a line "a3d-run: progress: N frames[ of T], F failed,
R frames/s" is printed at most every ``interval_s`` seconds (and once at the end), which a log
keeps readable. Messages go through ``write`` so that on a terminal they print above the bar.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from tqdm import tqdm

INTERVAL_S = 5.0


class LineProgress:
    """A progress line at most every ``interval_s`` seconds on a stream that is not a terminal."""

    def __init__(
        self,
        prog: str,
        total: int | None,
        stream: TextIO,
        interval_s: float = INTERVAL_S,
        clock=time.monotonic,
    ) -> None:
        self.prog, self.total, self.stream, self.interval_s, self.clock = (
            prog,
            total,
            stream,
            interval_s,
            clock,
        )
        self.started = self.last = clock()
        self.done = self.failed = self.reported = 0

    def update(self, failed: bool = False) -> None:
        self.done += 1
        self.failed += failed
        if self.clock() - self.last >= self.interval_s:
            self._line()

    def write(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    def close(self) -> None:
        if self.done != self.reported:
            self._line()

    def _line(self) -> None:
        self.last = now = self.clock()
        self.reported = self.done
        of = "" if self.total is None else f" of {self.total}"
        rate = self.done / (now - self.started) if now > self.started else 0.0
        self.write(
            f"{self.prog}: progress: {self.done} frames{of}, {self.failed} failed, {rate:.2f} frames/s"
        )


class BarProgress:
    """tqdm's bar (on a terminal)."""

    def __init__(self, prog: str, total: int | None, stream: TextIO) -> None:
        self.stream = stream
        self.bar = tqdm(total=total, desc=prog, unit="frame", file=stream)

    def update(self, failed: bool = False) -> None:
        self.bar.update()

    def write(self, text: str) -> None:
        tqdm.write(text, file=self.stream)

    def close(self) -> None:
        self.bar.close()


def make_progress(prog: str, total: int | None, stream: TextIO | None = None) -> LineProgress | BarProgress:
    """The bar on a terminal, progress lines otherwise."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return BarProgress(prog, total, stream) if isatty and isatty() else LineProgress(prog, total, stream)
