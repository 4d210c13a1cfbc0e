"""Frames from arrays in memory: the Python API's and every decoded stream's way in.

A caller hands colour, depth and intrinsics as arrays; this checks them the way the frame
readers check files and builds the pipeline's ``Frame``. Every problem is one ``ArrayError``
(a ValueError) that names the argument: ``"depth: 480x640 but color is 240x320"``.

Conventions: ``color`` is (H, W, 3) uint8 **RGB** (what cameras, PIL and most libraries hand
out; converted once to a3d's internal BGR); ``depth`` is (H, W) float32/float64 metres, or
uint16 in units of ``depth_scale`` metres (default 0.001: millimetres, the Kinect / RealSense
convention; TUM's 5000 units per metre is 0.0002); 0 means no measurement. ``intrinsics`` is
``(fx, fy, cx, cy)``, an ``Intrinsics`` or a 3 x 3 camera matrix, in the README's pixel convention
(``SourceOptions`` takes the same forms).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.frame import Frame, GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, check_rotation
from a3d.runtime.structures.pose import check_pose

MILLIMETRE = 0.001  # metres per unit of a uint16 depth map, unless told otherwise
PLAUSIBLE_MEDIAN_M = (0.1, 15.0)  # a room's median depth lies within; outside, the unit is likely wrong


class ArrayError(InputError):
    """An array or value handed to a3d in memory is unusable; the message names the argument."""


IntrinsicsLike = Intrinsics | Sequence[float] | np.ndarray


def intrinsics_from(value: IntrinsicsLike) -> Intrinsics:
    """``Intrinsics`` from (fx, fy, cx, cy), a 3 x 3 matrix or an ``Intrinsics``."""
    if isinstance(value, Intrinsics):
        return value
    try:
        numbers = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        expected = "expected (fx, fy, cx, cy) or a 3x3 matrix"
        raise ArrayError(f"intrinsics: {expected}, got {value!r:.80}") from None
    if numbers.shape == (3, 3):
        if numbers[0, 1] != 0 or numbers[1, 0] != 0 or tuple(numbers[2]) != (0.0, 0.0, 1.0):
            raise ArrayError("intrinsics: a camera matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        numbers = numbers[[0, 1, 0, 1], [0, 1, 2, 2]]
    if numbers.shape != (4,):
        raise ArrayError(f"intrinsics: expected (fx, fy, cx, cy) or a 3x3 matrix, got shape {numbers.shape}")
    try:
        return Intrinsics(*(float(v) for v in numbers))
    except InputError as e:
        raise ArrayError(str(e)) from None


def color_from(color: Any) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> a3d's BGR, contiguous."""
    if not isinstance(color, np.ndarray):
        raise ArrayError(f"color: expected a numpy array, got {type(color).__name__}")
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise ArrayError(f"color: expected an (H, W, 3) uint8 RGB array, got {color.dtype} {color.shape}")
    if min(color.shape[:2]) < 1:
        raise ArrayError(f"color: empty image {color.shape}")
    return np.ascontiguousarray(color[..., ::-1])


def depth_from(depth: Any, depth_scale: float | None = None) -> np.ndarray:
    """(H, W) metres float32 from float metres or uint16 units of ``depth_scale`` metres."""
    if not isinstance(depth, np.ndarray):
        raise ArrayError(f"depth: expected a numpy array, got {type(depth).__name__}")
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[..., 0]
    if depth.ndim != 2:
        raise ArrayError(f"depth: expected an (H, W) array, got shape {depth.shape}")
    if depth.dtype == np.uint16:
        scale = MILLIMETRE if depth_scale is None else check_depth_scale(depth_scale)
        return depth_units_to_metres(depth, scale)
    if depth.dtype not in (np.float32, np.float64):
        raise ArrayError(f"depth: expected float32 metres or uint16 with a depth scale, got {depth.dtype}")
    if depth_scale is not None:
        raise ArrayError("depth_scale: only for uint16 depth (float depth is in metres)")
    if not np.isfinite(depth).all():
        raise ArrayError("depth: has NaN or infinite values (use 0 for pixels without depth)")
    if (depth < 0).any():
        raise ArrayError(f"depth: has negative values (min {float(depth.min()):.3g})")
    return np.ascontiguousarray(depth, dtype=np.float32)


def check_depth_scale(value: Any) -> float:
    """``depth_scale`` as a float: a positive, finite number of metres per depth unit (ArrayError)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not 0 < value < np.inf:
        raise ArrayError(f"depth_scale: must be a positive number of metres per unit, got {value!r}")
    return float(value)


def depth_units_to_metres(depth: np.ndarray, scale: float) -> np.ndarray:
    """float32 metres of integer depth units of ``scale`` metres: divided by the whole number of
    units per metre where there is one (1000 for millimetres, 5000 for TUM), so that millimetres
    give exactly what the frame-folder reader gives (``float32(mm) / 1000``)."""
    per_metre = 1.0 / scale
    if abs(per_metre - round(per_metre)) < 1e-6 * per_metre:
        return depth.astype(np.float32) / np.float32(round(per_metre))
    return (depth.astype(np.float64) * scale).astype(np.float32)


def implausible_depth(depth_m: np.ndarray, integer: bool = True) -> str | None:
    """What is wrong when the median valid depth lies outside ``PLAUSIBLE_MEDIAN_M`` (no indoor
    scene: the unit is likely wrong, e.g. TUM's 5000 units per metre read as millimetres give
    17.7 m rooms), else None; ``integer``: the depth came as uint16 units (else as float, which
    must be metres). A sample of every 4th pixel each way keeps it cheap."""
    sample = depth_m[::4, ::4]
    valid = sample[sample > 0]
    if not valid.size:
        return None  # no depth at all: the pipeline's notes say so
    median = float(np.median(valid))
    low, high = PLAUSIBLE_MEDIAN_M
    if low <= median <= high:
        return None
    fix = (
        "check depth_scale (metres per uint16 unit: 0.001 for millimetres, the default; 0.0002 for TUM)"
        if integer
        else "float depth must be in metres (uint16 depth takes depth_scale)"
    )
    return f"depth: the median valid depth is {median:.3g} m, outside {low:g}-{high:g} m for a room; {fix}"


def _as_array_error(check: Callable[[Any, str], np.ndarray], value: Any, what: str) -> np.ndarray:
    """``check(value, what)``, its InputError raised as the ArrayError of the API."""
    try:
        return check(value, what)
    except InputError as e:
        raise ArrayError(str(e)) from None


def frame_from_arrays(
    color: Any,
    depth: Any,
    intrinsics: IntrinsicsLike,
    R_tilt: Any = None,
    *,
    depth_scale: float | None = None,
    name: str = "frame",
    origin: str = "",
    timestamp: float | None = None,
    truth: GroundTruth | None = None,
    pose: Any = None,
) -> Frame:
    """A checked ``Frame`` from arrays (see the module docstring for the conventions); ``pose``
    the 4 x 4 camera-to-world transform, if known (a3d.runtime.structures.pose)."""
    bgr = color_from(color)
    metres = depth_from(depth, depth_scale)
    if metres.shape != bgr.shape[:2]:
        raise ArrayError(
            f"depth: {metres.shape[0]}x{metres.shape[1]} but color is {bgr.shape[0]}x{bgr.shape[1]} "
            "(register and resize depth to the colour image first)"
        )
    K = intrinsics_from(intrinsics)
    rotation = None if R_tilt is None else _as_array_error(check_rotation, R_tilt, "R_tilt")
    camera_to_world = None if pose is None else _as_array_error(check_pose, pose, "pose")
    return Frame(
        name,
        bgr,
        metres,
        K,
        rotation,
        origin=origin or name,
        truth=truth,
        timestamp=timestamp,
        pose=camera_to_world,
    )
