"""Step 10, a3d.runtime.postprocess.long_axis: a long box a right angle off the way its object's
depth runs is turned along it; boxes along it, short boxes, doors and objects whose depth runs no
way in particular are left as they are."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.postprocess import long_axis as step
from a3d.runtime.postprocess.depth_support import STRIDE, SampledDepth
from a3d.runtime.structures.classes import class_index
from a3d.runtime.structures.geometry import Intrinsics, turned_by_yaw

K = Intrinsics(100.0, 100.0, 39.5, 29.5)
RNG = np.random.default_rng(3)
TABLE, DOOR = class_index("table"), class_index("door")
WHOLE = np.array([[0.0, 0.0, 80.0, 60.0]])  # the 2D box: every sample


def samples(x: tuple[float, float], z: tuple[float, float]) -> SampledDepth:
    """Depth samples of a table top 0.3 m below the camera, over ``x`` and ``z`` (metres)."""
    h, w = 60 // STRIDE, 80 // STRIDE
    points = np.stack(
        [RNG.uniform(*x, (h, w)), np.full((h, w), 0.3), RNG.uniform(*z, (h, w))], axis=-1
    )  # fmt: skip
    return SampledDepth(np.full((60, 80), 2.5), K, np.eye(3), points, np.ones((h, w), bool))


def runs_along(box: np.ndarray) -> np.ndarray:
    """The (x, z) direction of a box's length."""
    return turned_by_yaw(np.array([1.0, 0.0, 0.0]), box[6])[[0, 2]]


def test_a_box_across_a_long_table_seen_end_on_is_turned_along_it() -> None:
    sampled = samples((-0.3, 0.3), (2.0, 3.6))  # the table runs away from the camera
    across = np.array([[0.0, 0.3, 2.8, 1.6, 0.6, 0.7, 0.0]])  # its length along x
    turned = step.along_depth(sampled, WHOLE, across, np.array([TABLE]), np.array([0.9]))[0]
    assert abs(runs_along(turned)[1]) == pytest.approx(1.0, abs=1e-9)  # along z now
    np.testing.assert_allclose(turned[:6], across[0, :6])  # the same centre and size


def test_boxes_along_their_object_short_boxes_doors_and_round_objects_are_left() -> None:
    long_table = samples((-0.3, 0.3), (2.0, 3.6))
    along = np.array([[0.0, 0.3, 2.8, 1.6, 0.6, 0.7, np.pi / 2]])
    short = np.array([[0.0, 0.3, 2.8, 0.7, 0.6, 0.7, 0.0]])  # l < MIN_RATIO w: no way of its own
    across = np.array([[0.0, 0.3, 2.8, 1.6, 0.6, 0.7, 0.0]])
    for box, cls, sampled in (
        (along, TABLE, long_table),
        (short, TABLE, long_table),
        (across, DOOR, long_table),  # a door stands in its wall (steps 6 and 7)
        (across, TABLE, samples((-0.6, 0.6), (2.2, 3.4))),  # a square top: no way to turn it
    ):
        kept = step.along_depth(sampled, WHOLE, box, np.array([cls]), np.array([0.9]))
        np.testing.assert_allclose(kept, box)
    low = np.array([step.MIN_SCORE / 2])
    np.testing.assert_allclose(step.along_depth(long_table, WHOLE, across, np.array([TABLE]), low), across)
