"""Camera rate: the run always works on the newest frame of a live source and drops the stale ones.

A camera delivers frames at its own rate whether or not the detector keeps up; handing the run
every frame in order would make it fall further behind with each one. ``NewestFrames`` wraps a
source: a background thread takes the source's loaders as they come and keeps only the newest;
the run takes that one when it is ready for a frame, and each loader replaced before the run
took it is counted in ``dropped``. When the run stops taking frames (``--max-frames``, Ctrl-C,
an error) the thread stops reading and closes the source, so a camera's pipeline is stopped.

``realtime=True`` makes a recorded source (a bag, a folder with time stamps) behave like the
camera that recorded it: the thread reads each frame and releases it at its recorded time
(``Frame.timestamp``, relative to the first frame's), so a slow run drops frames exactly as it
would live. A frame without a time stamp cannot be paced: it is passed on with a one-line
problem instead ("ORIGIN: --realtime needs frame time stamps; none here").
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable, Iterator

from a3d.runtime.errors import InputError
from a3d.runtime.sources.base import FrameLoader, frame_loader

_DONE = object()
STOP_TIMEOUT_S = 10.0  # how long the run waits for the source to stop once it takes no more frames


class NewestFrames:
    """Iterate a source newest-first-only (see the module docstring); ``dropped`` counts stale frames."""

    def __init__(self, source: Iterable[FrameLoader], realtime: bool = False, clock=time.monotonic) -> None:
        self.source = source
        self.realtime = realtime
        self.clock = clock
        self.incomplete: list[str] = list(getattr(source, "incomplete", []))
        self.dropped = 0
        self._pending: object | None = None
        self._ready = threading.Condition()
        self._error: BaseException | None = None
        self._stop = threading.Event()

    def __iter__(self) -> Iterator[FrameLoader]:
        grabber = threading.Thread(target=self._grab, name="a3d-newest-frame", daemon=True)
        grabber.start()
        try:
            while True:
                with self._ready:
                    self._ready.wait_for(lambda: self._pending is not None)
                    item, self._pending = self._pending, None
                    self._ready.notify_all()
                if item is _DONE:
                    if self._error is not None:
                        raise self._error
                    return
                assert isinstance(item, FrameLoader)
                yield item
        finally:  # the run stopped taking frames (--max-frames, Ctrl-C, the end): stop the source too
            self._stop.set()
            with self._ready:
                self._ready.notify_all()
            grabber.join(timeout=STOP_TIMEOUT_S)

    def _publish(self, item: object) -> None:
        with self._ready:
            if self._pending is not None and self._pending is not _DONE:
                self.dropped += 1
            self._pending = item
            self._ready.notify_all()

    def _grab(self) -> None:
        start = first = None
        frames = iter(self.source)
        try:
            for loader in frames:
                if self._stop.is_set():
                    break
                if not self.realtime:
                    self._publish(loader)
                    continue
                try:
                    frame = loader.load()
                except Exception as error:  # reported by the run as the frame's problem
                    self._publish(FrameLoader(loader.name, loader.origin, _raiser(error), loader.files))
                    continue
                if frame.timestamp is None:
                    problem = InputError(
                        f"{loader.origin}: --realtime needs frame time stamps; this frame has none"
                    )
                    self._publish(FrameLoader(loader.name, loader.origin, _raiser(problem), loader.files))
                    continue
                if start is None:
                    start, first = self.clock(), frame.timestamp
                delay = start + (frame.timestamp - first) - self.clock()
                if delay > 0:
                    time.sleep(delay)
                self._publish(frame_loader(frame))
        except BaseException as error:  # the source itself failed: the run ends with it
            self._error = error
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()  # a generator source runs its cleanup now (a camera's pipeline.stop())
        with self._ready:  # the end is never dropped, and never drops the last frame
            self._ready.wait_for(lambda: self._pending is None or self._stop.is_set())
            self._pending = _DONE
            self._ready.notify_all()


def _raiser(error: BaseException):
    def load():
        raise error

    return load
