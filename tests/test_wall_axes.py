"""a3d.runtime.postprocess.wall_axes: the walls' direction from a frame's depth, and the yaws turned
square to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from a3d.runtime.postprocess.wall_axes import SNAP_DEG, square_to_walls, wall_direction
from a3d.runtime.structures.geometry import Intrinsics, canonical_boxes, rtilt_from_pitch_roll

K = Intrinsics(100.0, 100.0, 80.0, 60.0)
SIZE = (120, 160)


def room_corner_depth(turn_deg: float, R_tilt: np.ndarray, walls: bool = True) -> np.ndarray:
    """Depth (metres) of a room corner turned by ``turn_deg`` about gravity: a wall 3 m ahead, one
    2 m to the right (perpendicular), the floor 1.2 m below the camera; tilt-frame planes
    ``n . p = d``, seen through a camera whose ``p_tilt = R_tilt p_cam``."""
    phi = math.radians(turn_deg)
    planes = [((0.0, 1.0, 0.0), 1.2)]
    if walls:
        planes += [((math.sin(phi), 0.0, math.cos(phi)), 3.0), ((math.cos(phi), 0.0, -math.sin(phi)), 2.0)]
    v, u = np.indices(SIZE, dtype=np.float64)
    rays_cam = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(SIZE)], -1)
    rays = rays_cam @ np.asarray(R_tilt).T
    depth = np.full(SIZE, np.inf)
    for normal, d in planes:
        along = rays @ np.array(normal)
        t = np.where(along > 1e-6, d / np.where(along > 1e-6, along, 1.0), np.inf)
        depth = np.minimum(depth, t)  # rays_cam's z is 1: t is the camera-frame depth
    return np.where(np.isfinite(depth) & (depth < 10), depth, 0.0).astype(np.float32)


@pytest.mark.parametrize(("turn_deg", "expected_deg"), [(17.0, 17.0), (80.0, -10.0), (-30.0, -30.0)])
def test_the_walls_direction_modulo_a_quarter_turn_also_from_a_pitched_camera(
    turn_deg: float, expected_deg: float
) -> None:
    for R_tilt in (np.eye(3), rtilt_from_pitch_roll(math.radians(-15.0), math.radians(3.0))):
        direction = wall_direction(room_corner_depth(turn_deg, R_tilt), K, R_tilt)
        assert direction is not None
        assert math.degrees(direction) == pytest.approx(expected_deg, abs=0.5)


def test_no_direction_where_the_depth_shows_no_walls() -> None:
    assert wall_direction(room_corner_depth(17.0, np.eye(3), walls=False), K, np.eye(3)) is None
    assert wall_direction(np.zeros(SIZE, np.float32), K, np.eye(3)) is None


def test_yaws_near_a_wall_direction_are_turned_onto_it_the_others_kept() -> None:
    direction = math.radians(10.0)
    yaws = [10.0 + 12.0, 10.0 - 15.0 + 90.0, 10.0 + SNAP_DEG + 10.0, 10.0 - 45.0]
    boxes = canonical_boxes(np.array([[0.0, 0.0, 2.0, 1.0, 0.5, 0.8, math.radians(y)] for y in yaws]))
    squared = square_to_walls(boxes, direction)
    off = np.degrees((squared[:, 6] - direction + np.pi / 4) % (np.pi / 2) - np.pi / 4)
    np.testing.assert_allclose(off[:2], 0.0, atol=1e-9)  # turned square to the walls
    np.testing.assert_allclose(squared[2:], boxes[2:])  # too far from either: as they were
    np.testing.assert_array_equal(squared, canonical_boxes(squared))
    np.testing.assert_allclose(squared[:, :6], boxes[:, :6])  # only the yaw moves
    assert square_to_walls(np.zeros((0, 7)), direction).shape == (0, 7)
