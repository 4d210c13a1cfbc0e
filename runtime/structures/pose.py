"""Camera poses: 4 x 4 rigid camera-to-world transforms (metres), checked, and TUM's quaternions.

A pose ``T`` takes camera-frame points to the world: ``p_world = T[:3, :3] @ p_cam + T[:3, 3]``
(docs/sources.md "Camera poses"). Data sets write poses with a few decimals, so a pose is
accepted when its rotation is orthonormal with determinant 1 to within ``POSE_TOLERANCE`` and its
last row is ``0 0 0 1`` to within ``LAST_ROW_TOLERANCE``; it is then snapped to the nearest exact
rotation (SVD), so that nothing downstream inherits the file's rounding as a shear. Anything else
is an ``InputError`` whose one line names the pose and what is wrong with it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError

POSE_TOLERANCE = 1e-3  # max |R^T R - I| and |det R - 1| of an accepted pose's rotation
LAST_ROW_TOLERANCE = 1e-6
MAX_TRANSLATION_M = 1e6  # beyond this a translation is corrupt data, not a room
QUATERNION_NORM_TOLERANCE = 1e-2  # TUM writes 4 decimals; a quaternion this far from unit is corrupt


def check_pose(value: Any, what: str) -> np.ndarray:
    """``value`` as a float64 (4, 4) rigid transform, or InputError ``"what: ..."`` (module docstring)."""
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{what}: expected a 4x4 matrix of numbers") from None
    if T.shape != (4, 4):
        raise InputError(f"{what}: expected a 4x4 camera-to-world matrix, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise InputError(f"{what}: has NaN or infinite entries")
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > LAST_ROW_TOLERANCE:
        raise InputError(f"{what}: last row must be 0 0 0 1, got {_numbers(T[3])}")
    R = T[:3, :3]
    orthonormal = float(np.abs(R.T @ R - np.eye(3)).max())
    if orthonormal > POSE_TOLERANCE:
        raise InputError(
            f"{what}: not a rigid transform: its rotation is not orthonormal "
            f"(|R^T R - I| = {orthonormal:.2g} > {POSE_TOLERANCE:g})"
        )
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > POSE_TOLERANCE:
        raise InputError(f"{what}: not a rigid transform: det R = {det:.4g} (a reflection, not a rotation)")
    if np.abs(T[:3, 3]).max() > MAX_TRANSLATION_M:
        raise InputError(f"{what}: translation {_numbers(T[:3, 3])} is beyond {MAX_TRANSLATION_M:g} m")
    out = np.eye(4)
    out[:3, :3] = nearest_rotation(R)
    out[:3, 3] = T[:3, 3]
    return out


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation closest to ``R`` in the Frobenius norm (``U V^T`` of its SVD, det +1)."""
    u, _, vt = np.linalg.svd(np.asarray(R, np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 4 x 4 transform of rotation ``R`` (3, 3) and translation ``t`` (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def rigid_fit(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation and translation (4, 4) that best map the points ``source`` onto ``target``
    (least squares; Umeyama without scale)."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    R = nearest_rotation((target - mt).T @ (source - ms))
    return make_pose(R, mt - R @ ms)


def invert_pose(T: np.ndarray) -> np.ndarray:
    """World-to-camera of a camera-to-world pose (exact for a rigid one)."""
    R, t = T[:3, :3], T[:3, 3]
    return make_pose(R.T, -R.T @ t)


def rotation_deg(R: np.ndarray) -> float:
    """The angle, in degrees, that rotation ``R`` (3, 3) turns by."""
    return float(np.degrees(np.arccos(np.clip((np.trace(np.asarray(R, np.float64)) - 1) / 2, -1.0, 1.0))))


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``T`` applied to points (..., 3)."""
    return np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]


def quaternion_to_rotation(q: np.ndarray, what: str) -> np.ndarray:
    """The rotation of a quaternion ``(qx, qy, qz, qw)`` (TUM's order), normalised first;
    InputError when its norm is off by more than ``QUATERNION_NORM_TOLERANCE``."""
    q = np.asarray(q, np.float64)
    norm = float(np.linalg.norm(q))
    if not math.isfinite(norm) or abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise InputError(f"{what}: quaternion qx qy qz qw has norm {norm:.4g}, not 1")
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Unit quaternion a share ``s`` in [0, 1] of the way from ``q0`` to ``q1`` along the shorter
    arc (constant angular speed); nearly equal quaternions are interpolated linearly."""
    q0 = np.asarray(q0, np.float64) / np.linalg.norm(q0)
    q1 = np.asarray(q1, np.float64) / np.linalg.norm(q1)
    dot = float(q0 @ q1)
    if dot < 0.0:  # q and -q are one rotation: take the shorter way
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = math.acos(min(dot, 1.0))
    return (math.sin((1 - s) * angle) * q0 + math.sin(s * angle) * q1) / math.sin(angle)


def _numbers(values: np.ndarray) -> str:
    return " ".join(f"{v:.6g}" for v in np.asarray(values).ravel())
