"""Step 9, a3d.runtime.postprocess.hold_depth: a 3D box grown to hold what the depth shows of its
object, never shrunk, the background beyond its margin left out."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.postprocess import hold_depth as step
from a3d.runtime.postprocess.depth_support import sample_depth
from a3d.runtime.structures.geometry import Intrinsics

K = Intrinsics(100.0, 100.0, 79.5, 59.5)


def screen_before_a_wall() -> np.ndarray:
    """A 120 x 160 depth image: a wall 3 m away, and a 0.8 m square screen 2 m away in its middle."""
    depth = np.full((120, 160), 3.0)
    depth[40:80, 60:100] = 2.0  # x from -0.39 to 0.39, y from -0.39 to 0.39 at 2 m
    return depth


BOX2D = np.array([[55.0, 35.0, 105.0, 85.0]])


def test_a_box_regressed_behind_its_objects_surface_grows_to_hold_it_and_not_the_wall() -> None:
    sampled = sample_depth(screen_before_a_wall(), K, np.eye(3))
    behind = np.array([[0.0, 0.0, 2.1, 0.8, 0.1, 0.8, 0.0]])  # its front face 5 cm behind the screen
    grown = step.hold_depth(sampled, BOX2D, behind, np.array([0.9]))[0]
    front, back = grown[2] - grown[4] / 2, grown[2] + grown[4] / 2
    assert front == pytest.approx(2.0, abs=0.01)  # the screen is in it now
    assert back == pytest.approx(2.15, abs=0.005)  # the back face stays: the wall is 85 cm beyond
    assert grown[3] == pytest.approx(0.8, abs=0.02) and grown[5] == pytest.approx(0.8, abs=0.02)


def test_a_box_that_holds_its_object_low_scores_and_a_zero_margin_are_left_as_they_are(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sampled = sample_depth(screen_before_a_wall(), K, np.eye(3))
    holding = np.array([[0.0, 0.0, 2.05, 0.9, 0.2, 0.9, 0.0]])  # the screen inside it: never shrunk
    np.testing.assert_allclose(step.hold_depth(sampled, BOX2D, holding, np.array([0.9])), holding)
    behind = np.array([[0.0, 0.0, 2.1, 0.8, 0.1, 0.8, 0.0]])
    low = np.array([step.MIN_SCORE / 2])  # below step 5's floor: as it is
    np.testing.assert_allclose(step.hold_depth(sampled, BOX2D, behind, low), behind)
    monkeypatch.setattr(step, "MARGIN_M", 0.0)
    np.testing.assert_allclose(step.hold_depth(sampled, BOX2D, behind, np.array([0.9])), behind)


def test_the_floor_round_a_boxs_foot_is_not_its_objects() -> None:
    rows = np.indices((120, 160), dtype=np.float64)[0]
    below = (rows - K.cy) / K.fy  # the ray's drop per metre ahead; the floor 1 m below the camera
    depth = np.where(below > 0.01, 1.0 / np.maximum(below, 0.01), 0.0)
    depth = np.where(depth < 8.0, depth, 0.0)
    sampled = sample_depth(depth, K, np.eye(3))
    box = np.array([[0.0, 0.75, 3.0, 0.6, 0.6, 0.5, 0.0]])  # standing on the floor, nothing of it seen
    box2d = np.array([[60.0, 70.0, 100.0, 100.0]])  # its 2D box shows the floor round its foot
    kept = step.hold_depth(sampled, box2d, box, np.array([0.9]), floor=np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(kept, box)
    grown = step.hold_depth(sampled, box2d, box, np.array([0.9]))  # the floor taken for the object
    assert grown[0, 3] > box[0, 3] + 0.05
