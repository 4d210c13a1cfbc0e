"""a3d.runtime.postprocess.floor_contact: the floor found in the depth, and the boxes of the classes
that stand on it reaching down (or up) to it with their tops kept; other classes, boxes far from the
floor and frames without one left as they are."""

from __future__ import annotations

import math

import numpy as np
import pytest

from a3d.runtime.postprocess.depth_support import sample_depth
from a3d.runtime.postprocess.floor_contact import REACH_M, floor_plane, frame_floor, stand_on_floor
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from tests.helpers.point_layers import point_layer
from tests.test_wall_axes import SIZE, K, room_corner_depth

RNG = np.random.default_rng(0)
CHAIR, MONITOR = CLASSES.index("chair"), CLASSES.index("monitor")
FLOOR_Y = 1.2  # room_corner_depth's floor, below the camera (tilt-frame y is down)


def test_the_floor_is_the_lowest_layer_with_a_share_of_the_points_as_a_tilted_plane() -> None:
    floor = point_layer(RNG, 3000, lambda x, z: 0.01 * x + 0.02 * z + 1.4, (-2, 2), (1, 5))
    tables = point_layer(RNG, 30000, 0.7, (-1, 1), (2, 3))  # ten times the floor's points, higher up
    noise = point_layer(RNG, 20, 1.9, (-1, 1), (2, 3))  # a few wrong points below the floor
    np.testing.assert_allclose(floor_plane(np.vstack([floor, tables, noise])), [0.01, 0.02, 1.4], atol=1e-6)


def test_a_frame_s_floor_from_a_level_and_a_pitched_camera_and_none_without_depth() -> None:
    for R_tilt in (np.eye(3), rtilt_from_pitch_roll(math.radians(-15.0), math.radians(3.0))):
        plane = frame_floor(sample_depth(room_corner_depth(17.0, R_tilt), K, R_tilt))
        assert plane is not None
        np.testing.assert_allclose(plane, [0.0, 0.0, FLOOR_Y], atol=0.01)
    assert frame_floor(sample_depth(np.zeros(SIZE, np.float32), K, np.eye(3))) is None


def _box_at(bottom_y: float, height: float, R_tilt: np.ndarray) -> np.ndarray:
    """A 0.5 x 0.5 box of ``height`` whose bottom is at tilt-frame y ``bottom_y``, 2.5 m ahead,
    turned by 0.3 rad; its centre in the camera frame."""
    centre_tilt = np.array([0.4, bottom_y - height / 2, 2.5])
    return np.array([*(centre_tilt @ R_tilt), 0.5, 0.5, height, 0.3])  # p_cam = R^T p_tilt


def _bottom_top(box: np.ndarray, R_tilt: np.ndarray) -> tuple[float, float]:
    y = (R_tilt @ box[:3])[1]
    return y + box[5] / 2, y - box[5] / 2


def test_standing_boxes_near_the_floor_reach_it_with_their_tops_kept() -> None:
    R_tilt = rtilt_from_pitch_roll(math.radians(-12.0), math.radians(2.0))
    plane = np.array([0.0, 0.0, FLOOR_Y])
    floating = _box_at(FLOOR_Y - 0.25, 0.7, R_tilt)  # a chair's legs hidden: its box ends 25 cm up
    sunk = _box_at(FLOOR_Y + 0.1, 0.9, R_tilt)  # 10 cm into the floor
    far = _box_at(FLOOR_Y - REACH_M - 0.2, 0.5, R_tilt)  # on a table top, far above the floor
    monitor = _box_at(FLOOR_Y - 0.2, 0.4, R_tilt)
    boxes = np.array([floating, sunk, far, monitor])
    out = stand_on_floor(boxes, np.array([CHAIR, CHAIR, CHAIR, MONITOR]), plane, R_tilt)
    for before, after in zip(boxes[:2], out[:2], strict=True):
        bottom, top = _bottom_top(after, R_tilt)
        assert bottom == pytest.approx(FLOOR_Y, abs=1e-9)
        assert top == pytest.approx(_bottom_top(before, R_tilt)[1], abs=1e-9)  # the top kept
        footprint = np.delete(R_tilt @ after[:3], 1), np.delete(R_tilt @ before[:3], 1)
        np.testing.assert_allclose(*footprint, atol=1e-9)  # moved along gravity only
        np.testing.assert_allclose(after[[3, 4, 6]], before[[3, 4, 6]])  # l, w and yaw kept
    assert out[0][5] == pytest.approx(0.95) and out[1][5] == pytest.approx(0.8)
    np.testing.assert_array_equal(out[2:], boxes[2:])  # too far from the floor; not a standing class
