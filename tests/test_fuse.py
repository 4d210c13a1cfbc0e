"""a3d.runtime.postprocess.fuse: a 2D detector's boxes and a3d's own detections as one list, each
object once; a3d.runtime.frontend.box_pixels: a detector box's object pixels and initial centre."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.frontend.box_pixels import centres_of_masks, lift_boxes, object_masks_in_boxes
from a3d.runtime.postprocess.fuse import (
    NETWORK_REFERENCE,
    Picked,
    detector_picks,
    fused_score,
    merge,
)
from a3d.runtime.structures.classes import NUM_CLASSES, class_index
from a3d.runtime.structures.geometry import Intrinsics

CHAIR, MONITOR, TV, TABLE = (class_index(c) for c in ("chair", "monitor", "television", "table"))


def test_the_network_at_its_reference_leaves_the_detector_score_and_moves_it_either_way():
    detector = np.array([0.3, 0.6, 0.9])
    assert fused_score(detector, np.full(3, NETWORK_REFERENCE)) == pytest.approx(detector)
    assert np.all(fused_score(detector, np.full(3, 0.5)) > detector)
    assert np.all(fused_score(detector, np.full(3, 0.001)) < detector)
    # Increasing in both, within (0, 1).
    grid = fused_score(np.linspace(0.01, 0.99, 9)[:, None], np.linspace(0.01, 0.99, 9)[None, :])
    assert np.all(np.diff(grid, axis=0) > 0) and np.all(np.diff(grid, axis=1) > 0)
    assert np.all((grid > 0) & (grid < 1))


def test_a_box_of_several_candidate_classes_takes_the_one_the_network_prefers():
    scores = np.zeros((5, NUM_CLASSES))
    scores[3, MONITOR], scores[3, TV] = 0.6, 0.1  # row 3: the first detector box, a "tv"
    scores[4, MONITOR], scores[4, TV] = 0.05, 0.4  # row 4: the second
    scores[4, CHAIR] = 0.9  # not a candidate: never chosen
    candidates = np.zeros((2, NUM_CLASSES), bool)
    candidates[:, [MONITOR, TV]] = True
    boxes = np.array([[0, 0, 10, 10]] * 3 + [[0, 0, 100, 100], [200, 0, 300, 100]], float)
    picked = detector_picks(scores, boxes, 3, np.array([0.8, 0.7]), candidates, "yolox-nano")
    assert picked.rows.tolist() == [3, 4]
    assert picked.class_idx.tolist() == [MONITOR, TV]
    assert picked.scores == pytest.approx(fused_score(np.array([0.8, 0.7]), np.array([0.6, 0.4])))
    assert picked.sources == ("yolox-nano", "yolox-nano")


def test_boxes_of_two_detector_classes_that_become_one_a3d_class_on_one_object_count_once():
    sofa = class_index("sofa")
    scores = np.zeros((3, NUM_CLASSES))
    scores[:, CHAIR], scores[:, sofa] = 0.3, 0.1  # the network takes all three for chairs
    boxes = np.array([[0, 0, 100, 100], [4, 2, 100, 104], [300, 0, 400, 100]], float)
    candidates = np.zeros((3, NUM_CLASSES), bool)
    candidates[0, CHAIR] = True  # a "chair" box ...
    candidates[1:, [CHAIR, sofa]] = True  # ... and a "couch" box on the same object, one elsewhere
    picked = detector_picks(scores, boxes, 0, np.array([0.6, 0.8, 0.7]), candidates, "yolox-nano")
    assert picked.rows.tolist() == [1, 2]  # the better "couch" box is the object; the far one stays
    assert picked.class_idx.tolist() == [CHAIR, CHAIR]
    assert picked.scores == pytest.approx(fused_score(np.array([0.8, 0.7]), np.array([0.3, 0.3])))
    # Taken for different classes, the same boxes are two objects.
    scores[1, sofa] = 0.9
    picked = detector_picks(scores, boxes, 0, np.array([0.6, 0.8, 0.7]), candidates, "yolox-nano")
    assert picked.rows.tolist() == [0, 1, 2] and picked.class_idx.tolist() == [CHAIR, sofa, CHAIR]


def _picked(rows, classes, scores, source):
    return Picked(np.array(rows), np.array(classes), np.array(scores, float), (source,) * len(rows))


def test_an_object_both_find_is_reported_once_on_the_surer_ones_roi_with_the_better_score():
    boxes = np.array([
        [0, 0, 100, 100],  # 0: own chair
        [300, 0, 400, 100],  # 1: own table, nothing of the detector's near it
        [500, 0, 600, 100],  # 2: own monitor
        [5, 5, 100, 105],  # 3: detector chair on row 0's object (IoU ~0.86)
        [500, 0, 600, 100],  # 4: detector chair where the own detection is a monitor: two classes
    ], float)  # fmt: skip
    own = _picked([0, 1, 2], [CHAIR, TABLE, MONITOR], [0.9, 0.4, 0.7], "network")
    found = _picked([3, 4], [CHAIR, CHAIR], [0.6, 0.55], "yolox-nano")
    # The network (0.9) surer than the detector (0.5): its own RoI, row 0, carries the object.
    merged = merge(own, found, boxes, np.array([0.5, 0.5]))
    assert sorted(zip(merged.rows.tolist(), merged.sources, strict=True)) == [
        (0, "yolox-nano+network"), (1, "network"), (2, "network"), (4, "yolox-nano"),
    ]  # fmt: skip
    assert dict(zip(merged.rows.tolist(), merged.scores.tolist(), strict=True))[0] == pytest.approx(0.9)
    assert np.all(np.diff(merged.scores) <= 0)  # by descending score
    # The detector (0.95) surer: its box, row 3, with the better score of the two.
    merged = merge(own, found, boxes, np.array([0.95, 0.5]))
    assert sorted(merged.rows.tolist()) == [1, 2, 3, 4]
    assert dict(zip(merged.rows.tolist(), merged.scores.tolist(), strict=True))[3] == pytest.approx(0.9)
    assert merged.sources[merged.rows.tolist().index(3)] == "yolox-nano+network"


def test_without_detector_boxes_the_own_detections_are_kept_as_they_are():
    own = _picked([0, 1], [CHAIR, TABLE], [0.9, 0.4], "network")
    assert merge(own, _picked([], [], [], "yolox-nano"), np.zeros((2, 4)), np.zeros(0)) is own


def _scene() -> tuple[np.ndarray, np.ndarray]:
    """A chair-like block at 2 m in front of a wall at 4 m, one hole in the block."""
    depth = np.full((120, 160), 4.0, np.float32)
    depth[40:100, 60:110] = 2.0
    raw = depth.copy()
    raw[60:64, 80:84] = 0.0
    return raw, depth


def test_the_object_is_the_depth_layer_of_the_box_centre_not_the_wall_behind_it():
    raw, filled = _scene()
    box = np.array([[50, 30, 120, 110]], float)  # the block and a margin of wall around it
    (x0, y0), mask = object_masks_in_boxes(box, np.array([0.5]), raw, filled)[0]
    assert (x0, y0) == (50, 30)
    crop = filled[30:110, 50:120]
    assert np.all(mask == (crop == 2.0))  # the wall at 4 m is beyond the reach
    lifted = lift_boxes(box, np.array([0.5]), raw, filled, Intrinsics(100.0, 100.0, 80.0, 60.0))
    assert lifted.valid.tolist() == [True] and lifted.from_filled.tolist() == [False]
    z = lifted.centers[0, 2]
    assert z == pytest.approx(2.0)
    # The centroid of the block's pixels (u 84.5, v 69.5), back-projected at 2 m.
    assert lifted.centers[0, :2] == pytest.approx([(84.5 - 80) * z / 100, (69.5 - 60) * z / 100])


def test_a_box_without_depth_is_not_liftable():
    raw = np.zeros((50, 50), np.float32)
    box = np.array([[5, 5, 20, 20]], float)
    lifted = lift_boxes(box, np.array([0.5]), raw, raw, Intrinsics(50, 50, 25, 25))
    assert lifted.valid.tolist() == [False] and np.all(lifted.centers == 0)


def test_voters_pick_the_layer_a_segmenter_marks_instead_of_the_inner_half():
    """``voters`` (a segmentation network's pixels of the box's class) decide the layer: marking the
    wall's pixels makes the wall the object, as the inner half made the block; None keeps the rule."""
    raw, filled = _scene()
    box = np.array([[50, 30, 120, 110], [50, 30, 120, 110]], float)
    wall = np.zeros(raw.shape, bool)
    wall[30:110, 50:60] = True  # a strip of wall at the box's left edge
    masks = object_masks_in_boxes(box, np.array([0.5, 0.5]), raw, filled, [wall, None])
    crop = filled[30:110, 50:120]
    assert np.all(masks[0][1] == (crop == 4.0)) and np.all(masks[1][1] == (crop == 2.0))
    lifted = centres_of_masks(masks, raw, filled, Intrinsics(100.0, 100.0, 80.0, 60.0))
    assert lifted.centers[:, 2] == pytest.approx([4.0, 2.0])
