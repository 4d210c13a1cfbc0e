"""ROS messages (as ``rosbags`` deserialises them) to numpy: images, camera matrices, transforms.

Field names differ between ROS 1 and ROS 2 message types (``K`` / ``k``); both are read. Colour
comes back RGB (what ``frame_from_arrays`` takes), depth as uint16 units or float32 metres with
missing pixels 0 (ROS float depth marks them NaN). Every problem is an ``InputError`` whose
message the caller prefixes with the topic.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.geometry import Intrinsics

COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")  # mono16: the RealSense SDK's name for Z16
_COMPRESSED_DEPTH_HEADER = 12  # compressed_depth_image_transport's ConfigHeader before the PNG


def image_encoding(msg: Any) -> str:
    """``encoding`` of an Image, the format string of a CompressedImage."""
    return str(getattr(msg, "encoding", None) or getattr(msg, "format", ""))


def is_compressed(msg: Any) -> bool:
    return hasattr(msg, "format") and not hasattr(msg, "encoding")


def color_of(msg: Any) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour Image (rgb8, bgr8, rgba8, bgra8) or CompressedImage."""
    if is_compressed(msg):
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"cannot decode the compressed image ({msg.format!r})")
        return np.ascontiguousarray(image[..., ::-1])
    if msg.encoding not in COLOR_ENCODINGS:
        raise InputError(f"colour encoding {msg.encoding!r} is not one of {', '.join(COLOR_ENCODINGS)}")
    channels = 4 if msg.encoding.endswith("a8") else 3
    pixels = _rows(msg, np.dtype(np.uint8), channels)
    rgb = pixels[..., :3] if msg.encoding.startswith("rgb") else pixels[..., 2::-1]
    return np.ascontiguousarray(rgb)


def depth_of(msg: Any) -> np.ndarray:
    """(H, W) uint16 depth units (16UC1, mono16, compressedDepth PNG) or float32 metres (32FC1)."""
    if is_compressed(msg):
        if "compressedDepth" not in msg.format or "16UC1" not in msg.format:
            raise InputError(f"compressed depth {msg.format!r} is not a 16UC1 compressedDepth PNG")
        data = np.frombuffer(bytes(msg.data), np.uint8)[_COMPRESSED_DEPTH_HEADER:]
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16 or image.ndim != 2:
            raise InputError("cannot decode the compressedDepth PNG")
        return image
    if msg.encoding not in DEPTH_ENCODINGS:
        raise InputError(f"depth encoding {msg.encoding!r} is not one of {', '.join(DEPTH_ENCODINGS)}")
    if msg.encoding == "32FC1":
        metres = _rows(msg, np.dtype(np.float32), 1)[..., 0].astype(np.float32)
        metres[~np.isfinite(metres)] = 0.0
        return metres
    return _rows(msg, np.dtype(np.uint16), 1)[..., 0].astype(np.uint16)


def _rows(msg: Any, dtype: np.dtype, channels: int) -> np.ndarray:
    """The pixels of an Image as (H, W, channels), honouring ``step`` (row padding) and endianness."""
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if height < 1 or width < 1 or step < row_bytes or data.size < step * (height - 1) + row_bytes:
        raise InputError(f"image data of {data.size} bytes does not hold {height}x{width} {msg.encoding}")
    rows = np.lib.stride_tricks.as_strided(data, (height, row_bytes), (step, 1))
    order = ">" if msg.is_bigendian else "<"
    return rows.copy().view(dtype.newbyteorder(order)).reshape(height, width, channels)


def intrinsics_of(info: Any) -> Intrinsics:
    """Intrinsics of a CameraInfo's K (ROS 1 ``K``, ROS 2 ``k``); InputError if uncalibrated."""
    K = np.asarray(getattr(info, "K", None) if hasattr(info, "K") else info.k, np.float64).reshape(3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError("camera_info has no calibration (K is zero)")
    return Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2])


POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")


def pose_row_of(msg: Any) -> np.ndarray:
    """``t tx ty tz qx qy qz qw`` (a trajectory row: stamp in s) of a PoseStamped or an Odometry
    (its ``pose.pose``; the covariance and twist are not used)."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return _row(header_seconds(msg), pose.position, pose.orientation)


def transform_row_of(stamped: Any) -> np.ndarray:
    """The trajectory row of a TransformStamped: the child frame's pose in the parent frame."""
    return _row(header_seconds(stamped), stamped.transform.translation, stamped.transform.rotation)


def _row(stamp: float, p: Any, q: Any) -> np.ndarray:
    return np.array([stamp, p.x, p.y, p.z, q.x, q.y, q.z, q.w], np.float64)


def transform_of(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a geometry_msgs/Transform: ``p_parent = R p_child + t``."""
    q = msg.rotation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        raise InputError("transform has a zero rotation quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    tr = msg.translation
    return R, np.array([float(tr.x), float(tr.y), float(tr.z)])


def header_seconds(msg: Any) -> float:
    """The header stamp in seconds (ROS 1 ``secs``/``nsecs`` or ROS 2 ``sec``/``nanosec``)."""
    stamp = msg.header.stamp
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9
