"""A fake ``pyrealsense2`` at the SDK boundary: the calls a3d's RealSense source makes, with the
SDK's shapes (pipeline, config, align, framesets, stream profiles, the depth sensor's scale),
serving given frames as a camera would.

tests/test_source_realsense.py puts it in ``sys.modules``; bench/newcomer.py --wheel imports it
by its path from a stub ``pyrealsense2`` package (``folder_camera``), so it needs numpy and OpenCV
only (the base install), nothing of tests/ or a3d.
"""

from __future__ import annotations

import json
import time
import types
from pathlib import Path

import cv2
import numpy as np

DEPTH_SCALE = 0.001


class _Frame:
    def __init__(self, pixels: np.ndarray, layout: str) -> None:
        self.pixels, self.layout = pixels, layout

    def get_data(self) -> np.ndarray:
        return self.pixels

    def get_profile(self) -> types.SimpleNamespace:
        return types.SimpleNamespace(format=lambda: self.layout)

    def __bool__(self) -> bool:
        return True


class _Frameset:
    def __init__(self, color: _Frame, depth: _Frame, ms: float) -> None:
        self.color, self.depth, self.ms = color, depth, ms

    def get_color_frame(self) -> _Frame:
        return self.color

    def get_depth_frame(self) -> _Frame:
        return self.depth

    def get_timestamp(self) -> float:
        return self.ms


def fake_sdk(
    frames: list,
    intrinsics: tuple[float, float, float, float],
    serials: tuple[str, ...] = ("123",),
    interrupt_at: int | None = None,
    period: float = 0.6,
) -> types.ModuleType:
    """A ``pyrealsense2`` stand-in serving ``frames`` ((BGR, uint16 depth) pairs, depth already
    aligned, seen by a colour camera of ``intrinsics`` (fx, fy, cx, cy)), one every ``period``
    seconds like a camera (slower than the tiny model needs, so a run takes every frame; 0 serves
    them at once and the run drops the stale ones); ``log`` records the calls a3d made.
    ``interrupt_at``: raise KeyboardInterrupt (as Ctrl-C does) when that frame is waited for."""
    rs = types.ModuleType("pyrealsense2")
    rs.log = log = []
    rs.stream = types.SimpleNamespace(depth="depth", color="color")
    rs.format = types.SimpleNamespace(rgb8="rgb8", bgr8="bgr8", z16="z16")
    rs.camera_info = types.SimpleNamespace(serial_number="serial_number")

    class Device:
        def __init__(self, serial: str) -> None:
            self.serial = serial

        def get_info(self, what: str) -> str:
            assert what == "serial_number"
            return self.serial

        def first_depth_sensor(self) -> types.SimpleNamespace:
            return types.SimpleNamespace(get_depth_scale=lambda: DEPTH_SCALE)

    class Config:
        def enable_device(self, serial: str) -> None:
            log.append(("enable_device", serial))

        def enable_stream(self, stream: str, *layout: str) -> None:
            log.append(("enable_stream", stream, *layout))

    class Pipeline:
        def __init__(self) -> None:
            self.served = 0

        def start(self, config: Config) -> types.SimpleNamespace:
            log.append(("start",))
            height, width = frames[0][1].shape if frames else (0, 0)
            fx, fy, cx, cy = intrinsics
            intr = types.SimpleNamespace(width=width, height=height, fx=fx, fy=fy, ppx=cx, ppy=cy)
            video = types.SimpleNamespace(get_intrinsics=lambda: intr)
            stream = types.SimpleNamespace(as_video_stream_profile=lambda: video)
            return types.SimpleNamespace(get_device=lambda: Device(serials[0]), get_stream=lambda s: stream)

        def try_wait_for_frames(self, timeout_ms: int) -> tuple[bool, _Frameset | None]:
            if self.served == interrupt_at:
                raise KeyboardInterrupt
            if self.served >= len(frames):
                return False, None  # a live camera that stalled
            time.sleep(period)
            color, depth = frames[self.served]
            self.served += 1
            return True, _Frameset(_Frame(color, "bgr8"), _Frame(depth, "z16"), 1000.0 * self.served)

        def stop(self) -> None:
            log.append(("stop",))

    class Align:
        def __init__(self, to: str) -> None:
            assert to == "color"  # depth aligned to colour, as a3d needs

        def process(self, frameset: _Frameset) -> _Frameset:
            log.append(("align",))
            return frameset

    rs.context = lambda: types.SimpleNamespace(query_devices=lambda: [Device(s) for s in serials])
    rs.config, rs.pipeline, rs.align = Config, Pipeline, Align
    return rs


def folder_camera(folder: Path, repeat: int = 1, period: float = 0.6) -> types.ModuleType:
    """``fake_sdk`` serving an a3d frame folder's frames (``*.color.png`` with their ``*.depth.png``
    in millimetres, the folder's ``intrinsics.json``) in name order, the whole folder ``repeat``
    times: a camera that streams ``repeat`` times as many frames before it stalls."""
    k = json.loads((folder / "intrinsics.json").read_text())
    frames = [
        (
            cv2.imread(str(color), cv2.IMREAD_COLOR),
            cv2.imread(str(color).replace(".color.png", ".depth.png"), cv2.IMREAD_UNCHANGED),
        )
        for color in sorted(folder.glob("*.color.png"))
    ]
    return fake_sdk(frames * repeat, (k["fx"], k["fy"], k["cx"], k["cy"]), period=period)
