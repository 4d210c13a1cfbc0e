"""What ``--intrinsics``, ``--depth-scale`` and ``--resize-depth`` do, the same for every source.

A camera's own numbers are sometimes wrong or missing (an uncalibrated sensor, a data set whose
depth unit is not millimetres), so a3d-run lets the user replace them. ``open_source`` wraps every
source with ``with_overrides``, so a reader only says what its files say:

* ``--intrinsics fx,fy,cx,cy`` (or a named preset, ``INTRINSICS_PRESETS``) replaces every frame's
  intrinsics;
* ``--depth-scale S`` (metres per depth unit) replaces the unit of a source that reads integer
  depth: the source says its own unit in its ``depth_scale`` attribute, the wrapper takes each
  depth value back to the integer the file held (exact: ``depth_units_to_metres`` divides whole
  units) and converts it with S instead. Depth that is float metres in its file (a ``.npy``, a
  point cloud) has no unit to replace: one line says so;
* ``--world-up AXIS`` (a3d-run): the poses' world is gravity-aligned with AXIS up, so each posed
  frame without its own ``R_tilt`` gets the one its pose gives (a3d.runtime.mapping.world
  ``rtilt_from_pose``), its line's gravity "given", instead of an estimate from the depth;
* ``--resize-depth``: depth of another size than the colour image is refused with one line unless
  it is given; then the reader resizes the depth map to the colour image with nearest-neighbour
  sampling (no depth is invented between a near and a far surface) through ``fit_depth``. The
  depth must already be registered to the colour camera with the same field of view.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.mapping.world import rtilt_from_pose
from a3d.runtime.sources.arrays import depth_units_to_metres
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.wording import keyword, option
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics

INTRINSICS_PRESETS: dict[str, Intrinsics] = {
    "fr1": Intrinsics(517.3, 516.5, 318.6, 255.3),
    "fr2": Intrinsics(520.9, 521.0, 325.1, 249.7),
    "fr3": Intrinsics(535.4, 539.2, 320.1, 247.6),
}
"""Named intrinsics ``--intrinsics NAME`` accepts: the TUM RGB-D benchmark's published colour
camera calibrations of its freiburg1/2/3 Kinects (640 x 480)."""


def parse_intrinsics(text: str) -> Intrinsics:
    """``--intrinsics``: "fx,fy,cx,cy" in pixels or a preset name (InputError naming the flag)."""
    name = text.strip().lower().replace("freiburg", "fr")
    if name in INTRINSICS_PRESETS:
        return INTRINSICS_PRESETS[name]
    parts = text.replace(" ", "").split(",")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        presets = "|".join(INTRINSICS_PRESETS)
        raise InputError(f"--intrinsics: expected fx,fy,cx,cy (4 numbers) or one of {presets}, got {text!r}")
    try:
        return Intrinsics(*values)
    except InputError as e:
        raise InputError(f"--intrinsics: {e}") from None


def parse_depth_scale(text: str) -> float:
    """``--depth-scale``: a positive number of metres per depth unit (0.001 = millimetres)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"--depth-scale: expected metres per depth unit (e.g. 0.001), got {text!r}")
    return value


def fit_depth(depth: np.ndarray, color_size: tuple[int, int], resize: bool, path: Path | str) -> np.ndarray:
    """Depth of the colour image's (H, W): as it is, resized (nearest) when ``resize``, else InputError."""
    if depth.shape[:2] == tuple(color_size):
        return depth
    (h, w), (ch, cw) = depth.shape[:2], color_size
    if not resize:
        raise InputError(
            f"{path}: depth is {h}x{w} but colour is {ch}x{cw} "
            f"({option('resize_depth')} resizes registered depth)"
        )
    return cv2.resize(depth, (cw, ch), interpolation=cv2.INTER_NEAREST)


class OverriddenSource:
    """A source whose frames get the user's intrinsics and depth unit (module docstring)."""

    def __init__(
        self,
        source: Any,
        intrinsics: Intrinsics | None,
        depth_scale: float | None,
        world_down: np.ndarray | None = None,
    ) -> None:
        self.source = source
        self.incomplete: list[str] = source.incomplete
        self.intrinsics = intrinsics
        self.depth_scale = depth_scale
        self.world_down = world_down
        self.has_poses: bool = getattr(source, "has_poses", False)

    def __iter__(self) -> Iterator[FrameLoader]:
        for loader in self.source:
            yield FrameLoader(loader.name, loader.origin, partial(self._load, loader), loader.files)

    def _load(self, loader: FrameLoader) -> Frame:
        return self.apply(loader.load())

    def apply(self, frame: Frame) -> Frame:
        changes: dict[str, Any] = {}
        if self.intrinsics is not None:
            changes["intrinsics"] = self.intrinsics
        if self.depth_scale is not None:
            native = getattr(self.source, "depth_scale", None)
            where = frame.depth_file or frame.origin
            if native is None or (frame.depth_file or "").lower().endswith(".npy"):
                given = keyword("depth_scale")
                raise InputError(f"{where}: {given}: this depth is float metres, it has no unit to set")
            units = np.rint(frame.depth.astype(np.float64) / native).astype(np.int64)
            changes["depth"] = depth_units_to_metres(units, self.depth_scale)
        if self.world_down is not None and frame.pose is not None and frame.R_tilt is None:
            changes["R_tilt"] = rtilt_from_pose(frame.pose, self.world_down)
        return replace(frame, **changes) if changes else frame


class _SizedOverriddenSource(OverriddenSource):
    """The same, for a source that knows its number of frames (the run's progress bar uses it)."""

    def __len__(self) -> int:
        return len(self.source)


def with_overrides(
    source: Any,
    intrinsics: Intrinsics | None,
    depth_scale: float | None,
    world_down: np.ndarray | None = None,
) -> Any:
    """``source`` itself when nothing is overridden, else its ``OverriddenSource`` (``world_down``:
    the gravity of the poses' world, for --world-up)."""
    if intrinsics is None and depth_scale is None and world_down is None:
        return source
    kind = _SizedOverriddenSource if hasattr(source, "__len__") else OverriddenSource
    return kind(source, intrinsics, depth_scale, world_down)
