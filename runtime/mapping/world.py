"""Boxes between a posed camera and the world (docs/mapping.md "The world frame").

a3d's gravity-aligned world has y along gravity, pointing down, as the tilt frame has: a box in it
is the same 7-vector ``[x, y, z, l, w, h, theta]`` as in a camera (docs/conventions.md "3D boxes")
with ``R_tilt`` the identity, its yaw ``theta = atan2(dx, dz)`` about the world's y axis. A pose
``T`` (4 x 4, camera-to-world, a3d.runtime.structures.pose) takes camera points to it.

Boxes are moved through their 8 corners (``box_corners_camera`` -> ``T`` -> the target's tilt
frame -> ``boxes_from_corners_tilt``), one path whatever the frame's gravity: exact (to rounding) when
the frame's ``R_tilt`` agrees with the world's gravity, and the best-fitting box when an
estimated ``R_tilt`` leans a little.
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.gravity import rtilt_from_gravity
from a3d.runtime.structures.geometry import box_corners_camera, boxes_from_corners_tilt
from a3d.runtime.structures.pose import invert_pose, transform_points

WORLD_DOWN = np.array([0.0, 1.0, 0.0])  # gravity in the world frame
IDENTITY = np.eye(3)


def rtilt_from_pose(pose: np.ndarray, down: np.ndarray = WORLD_DOWN) -> np.ndarray:
    """The camera's ``R_tilt`` (R_x(pitch) R_z(roll)) from its pose in a gravity-aligned world
    whose gravity is ``down`` (a3d's: y): gravity in the camera is ``R^T down``."""
    return rtilt_from_gravity(pose[:3, :3].T @ np.asarray(down, np.float64))


WORLD_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")


def down_of_up_axis(axis: str) -> np.ndarray:
    """Gravity (down) of a world whose ``axis`` ("+z", "-y", ...) points up (InputError otherwise)."""
    if axis not in WORLD_AXES:
        raise InputError(f"--world-up: expected one of {', '.join(WORLD_AXES)}, got {axis!r}")
    down = np.zeros(3)
    down["xyz".index(axis[1])] = -1.0 if axis[0] == "+" else 1.0
    return down


def boxes_to_world(boxes: np.ndarray, R_tilt: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Camera-frame boxes (N, 7) (theta in the frame's tilt frame ``R_tilt``) as world boxes (N, 7)."""
    corners = transform_points(pose, box_corners_camera(boxes, R_tilt))
    return boxes_from_corners_tilt(corners, IDENTITY)  # the world is its own tilt frame


def boxes_to_camera(boxes: np.ndarray, pose: np.ndarray, R_tilt: np.ndarray) -> np.ndarray:
    """World boxes (N, 7) as boxes (N, 7) of the camera at ``pose``, theta in its tilt frame ``R_tilt``."""
    corners = transform_points(invert_pose(pose), box_corners_camera(boxes, IDENTITY))
    return boxes_from_corners_tilt(corners @ np.asarray(R_tilt, np.float64).T, R_tilt)  # tilt-frame corners


def box_differences(a: np.ndarray, b: np.ndarray, square_tolerance: float = 1e-9) -> np.ndarray:
    """(N,) largest difference between paired boxes (metres, and radians of yaw), up to the box's
    own symmetry: yaw modulo pi, or modulo pi/2 for a square footprint (l = w), where every
    quarter turn is the same box and no 7-vector is preferred."""
    a, b = np.asarray(a, np.float64).reshape(-1, 7), np.asarray(b, np.float64).reshape(-1, 7)
    shape = np.abs(a[:, :6] - b[:, :6]).max(axis=1)
    square = (np.abs(a[:, 3] - a[:, 4]) <= square_tolerance) & (np.abs(b[:, 3] - b[:, 4]) <= square_tolerance)
    period = np.where(square, np.pi / 2, np.pi)
    turn = np.abs((a[:, 6] - b[:, 6] + period / 2) % period - period / 2)
    return np.maximum(shape, turn)


def same_boxes(boxes: np.ndarray, candidates: np.ndarray, tolerance: float = 1e-4) -> np.ndarray:
    """(N,) for each of ``boxes`` the row of ``candidates`` that is the same box (``box_differences``
    within ``tolerance``: rounding, not error), -1 where none is."""
    boxes, candidates = np.asarray(boxes).reshape(-1, 7), np.asarray(candidates).reshape(-1, 7)
    out = np.full(len(boxes), -1, np.int64)
    for i, box in enumerate(boxes):
        if len(candidates):
            differences = box_differences(candidates, np.repeat(box[None], len(candidates), axis=0))
            k = int(np.argmin(differences))
            out[i] = k if differences[k] <= tolerance else -1
    return out
