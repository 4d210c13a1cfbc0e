"""Camera rate: a live source hands the run its newest frame and counts the stale ones it dropped."""

from __future__ import annotations

import time

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.sources.base import FrameLoader, frame_loader
from a3d.runtime.sources.newest import NewestFrames
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics

K = Intrinsics(50.0, 50.0, 15.5, 11.5)


def _frame(i: int, timestamp: float | None) -> Frame:
    return Frame(
        f"f{i}", np.zeros((24, 32, 3), np.uint8), np.ones((24, 32), np.float32), K, timestamp=timestamp
    )


class Camera:
    """Yields a loader every ``period`` seconds, like a camera that does not wait for its reader."""

    def __init__(self, n: int, period: float) -> None:
        self.n, self.period = n, period
        self.incomplete = ["cam: one broken setting"]

    def __iter__(self):
        for i in range(self.n):
            time.sleep(self.period)
            yield frame_loader(_frame(i, None))


def test_a_slow_run_gets_the_newest_frame_and_counts_the_dropped_ones() -> None:
    live = NewestFrames(Camera(40, 0.005))
    taken = []
    for loader in live:
        taken.append(int(loader.name[1:]))
        time.sleep(0.03)  # the run is ~6x slower than the camera
    assert taken == sorted(taken) and taken[-1] == 39  # in order, and the last frame is never lost
    assert live.dropped == 40 - len(taken) and live.dropped > 20
    assert live.incomplete == ["cam: one broken setting"]


def test_a_fast_run_drops_nothing() -> None:
    live = NewestFrames(Camera(10, 0.01))
    assert [loader.name for loader in live] == [f"f{i}" for i in range(10)] and live.dropped == 0


def test_realtime_plays_a_recording_at_its_rate() -> None:
    recorded = [frame_loader(_frame(i, 100.0 + 0.05 * i)) for i in range(6)]  # 20 frames/s
    live = NewestFrames(recorded, realtime=True)
    start = time.monotonic()
    names = [loader.name for loader in live]
    elapsed = time.monotonic() - start
    assert names == [f"f{i}" for i in range(6)] and live.dropped == 0
    assert 0.24 <= elapsed < 1.0  # the last frame comes 0.25 s after the first


def test_realtime_needs_time_stamps_and_passes_bad_frames_on_as_problems() -> None:
    def broken():
        raise InputError("x.png: unreadable")

    [unstamped] = NewestFrames([frame_loader(_frame(0, None))], realtime=True)
    with pytest.raises(InputError, match=r"^f0: --realtime needs frame time stamps"):
        unstamped.load()
    [bad] = NewestFrames([FrameLoader("bad", "x.png", broken)], realtime=True)
    with pytest.raises(InputError, match=r"^x.png: unreadable$"):
        bad.load()


def test_a_run_that_stops_taking_frames_stops_the_source() -> None:
    """--max-frames or Ctrl-C: the reader thread stops and the source's cleanup runs (a camera's
    pipeline.stop()), instead of a camera left streaming into a thread nobody reads."""
    closed = []

    def camera():
        try:
            for i in range(1000):
                time.sleep(0.002)
                yield frame_loader(_frame(i, None))
        finally:
            closed.append(True)

    live = NewestFrames(camera())
    frames = iter(live)
    taken = [next(frames), next(frames)]
    frames.close()
    assert len(taken) == 2 and closed == [True]
