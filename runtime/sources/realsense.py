"""Frames from an Intel RealSense camera, live or a recording played by the SDK, via pyrealsense2.

``a3d-run realsense`` opens the first camera, ``realsense:SERIAL`` the one with that serial
number, ``realsense:FILE`` (a ``.bag`` / ``.db3`` the SDK recorded) plays the recording through
the SDK instead (as fast as frames are taken, not in real time). pyrealsense2 (the ``realsense``
extra) is imported only here.

Depth is aligned to colour by the SDK (``rs.align(rs.stream.color)``), so frames need no
registration of their own; intrinsics are the colour stream's (the SDK's pixel convention, pixel
centres at integer coordinates, is a3d's), the depth scale the depth sensor's
(``get_depth_scale()``); ``--intrinsics`` / ``--depth-scale`` override them. A live camera
streams until ``--max-frames`` or Ctrl-C; the pipeline is stopped whichever way the run ends.
A camera is a live source (``live``): the run takes its newest frame and the live front end. The
SDK's playback of a recording sometimes delivers no frameset at all (pyrealsense2 2.59, short
recordings); a recording that gave none is reported as a failed frame, not as an empty run.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.sources.arrays import frame_from_arrays
from a3d.runtime.sources.base import FrameLoader, frame_loader
from a3d.runtime.sources.registry import SourceOptions
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics

EXTRA = "pip install 'a3d[realsense]'"
SCHEME = "realsense"
FRAME_TIMEOUT_MS = 5000  # a live camera that sends nothing for this long has stopped


def claims(spec: str) -> bool:
    return spec == SCHEME or spec.startswith(f"{SCHEME}:")


def open_source(spec: str, options: SourceOptions) -> RealSenseSource:
    return RealSenseSource(spec, options)


class RealSenseSource:
    """A started RealSense pipeline as a ``FrameSource`` (frames are read as the run asks)."""

    def __init__(self, spec: str, options: SourceOptions) -> None:
        self.spec = spec
        self.options = options
        self.incomplete: list[str] = []
        self.rs = _import_sdk(spec)
        target = spec.partition(":")[2]
        self.recording = Path(target) if target and Path(target).is_file() else None
        self.live = self.recording is None  # a camera streams whether or not the run keeps up
        config = self.rs.config()
        if self.recording is not None:
            config.enable_device_from_file(str(self.recording), False)  # no repeat: the file ends the run
        else:
            self._check_connected(target)
            if target:
                config.enable_device(target)
            config.enable_stream(self.rs.stream.depth)
            config.enable_stream(self.rs.stream.color, self.rs.format.rgb8)
        self.pipeline = self.rs.pipeline()
        try:
            profile = self.pipeline.start(config)
        except RuntimeError as e:
            raise InputError(f"{spec}: cannot start the camera ({e})") from None
        self.playback = None
        if self.recording is not None:  # paused until the run takes frames (the model loads first)
            self.playback = profile.get_device().as_playback()
            self.playback.set_real_time(False)
            self.playback.pause()
        self.depth_scale = options.depth_scale or float(
            profile.get_device().first_depth_sensor().get_depth_scale()
        )
        sdk = profile.get_stream(self.rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics = options.intrinsics or Intrinsics(sdk.fx, sdk.fy, sdk.ppx, sdk.ppy)
        self.align = self.rs.align(self.rs.stream.color)

    def _check_connected(self, serial: str) -> None:
        info = self.rs.camera_info.serial_number
        serials = [device.get_info(info) for device in self.rs.context().query_devices()]
        if not serials:
            raise InputError(f"{self.spec}: no RealSense camera connected")
        if serial and serial not in serials:
            raise InputError(f"{self.spec}: no camera with serial {serial} (connected: {', '.join(serials)})")

    def __iter__(self) -> Iterator[FrameLoader]:
        index = 0
        if self.playback is not None:
            self.playback.resume()
        try:
            while True:
                ok, frames = self.pipeline.try_wait_for_frames(FRAME_TIMEOUT_MS)
                if not ok:  # a camera that stalled, or a recording's end (a failure if it gave nothing)
                    if self.recording is None:
                        problem = f"{self.spec}: no frames for {FRAME_TIMEOUT_MS / 1000:g} s; stopped"
                    else:
                        problem = f"{self.spec}: the SDK's playback delivered no frames (try again)"
                    if self.recording is None or index == 0:
                        yield FrameLoader(f"{SCHEME}_{index:06d}", self.spec, _fail(problem))
                    return
                frame = self._frame(self.align.process(frames), index)
                if frame is not None:
                    yield frame_loader(frame)
                    index += 1
        finally:
            self.pipeline.stop()

    def _frame(self, frames: Any, index: int) -> Frame | None:
        """The aligned frameset as a Frame (None when it lacks colour or depth)."""
        color, depth = frames.get_color_frame(), frames.get_depth_frame()
        if not color or not depth:
            return None
        rgb = np.asanyarray(color.get_data()).copy()
        layout = color.get_profile().format()
        if layout == self.rs.format.bgr8:
            rgb = rgb[..., ::-1]
        elif layout != self.rs.format.rgb8:
            raise InputError(f"{self.spec}#{index}: colour format {layout} is not rgb8 or bgr8")
        units = np.asanyarray(depth.get_data()).copy()
        name = f"{SCHEME}_{index:06d}"
        return frame_from_arrays(
            rgb,
            units,
            self.intrinsics,
            depth_scale=self.depth_scale,
            name=name,
            origin=f"{self.spec}#{index}",
            timestamp=float(frames.get_timestamp()) / 1000.0,
        )


def _fail(problem: str) -> Any:
    def load() -> Frame:
        raise InputError(problem)

    return load


def _import_sdk(spec: str) -> Any:
    try:
        import pyrealsense2
    except ImportError as e:
        raise InputError(f"{spec}: the RealSense source needs pyrealsense2: {EXTRA} ({e})") from None
    return pyrealsense2
