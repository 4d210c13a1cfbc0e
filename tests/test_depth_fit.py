"""a3d.runtime.postprocess.depth_fit: a door's box slid onto the surface the depth shows, other
classes and low scores left where they are."""

from __future__ import annotations

import numpy as np

from a3d.runtime.postprocess.depth_fit import MIN_SCORE, REACH_M, fit_to_depth
from a3d.runtime.postprocess.depth_support import sample_depth
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import Intrinsics, project_boxes_to_2d

K = Intrinsics(100.0, 100.0, 80.0, 60.0)
SIZE = (120, 160)
WALL_Z = 3.0
DOOR = np.array([0.0, 0.0, WALL_Z + 0.02, 0.9, 0.04, 2.0, 0.0])  # flat in the wall, its face at 3 m
DOOR_IDX, CHAIR_IDX = CLASSES.index("door"), CLASSES.index("chair")


def _depth() -> np.ndarray:
    """A level camera facing a wall 3 m ahead (the door a slab flush with it)."""
    return np.full(SIZE, WALL_Z)


def _fit(boxes: np.ndarray, classes: list[int], scores: list[float]) -> np.ndarray:
    boxes2d = project_boxes_to_2d(DOOR[None].repeat(len(boxes), 0), np.eye(3), K, SIZE)
    sampled = sample_depth(_depth(), K, np.eye(3))
    return fit_to_depth(sampled, boxes2d, boxes, np.array(classes), np.array(scores))


def test_a_door_regressed_in_front_of_its_wall_is_slid_back_onto_it() -> None:
    for off in (-0.25, -0.15, 0.2):  # in front of the wall (seen through) and behind it (holds nothing)
        moved = DOOR.copy()
        moved[2] += off
        (fitted,) = _fit(moved[None], [DOOR_IDX], [0.9])
        assert abs(fitted[2] - DOOR[2]) <= 0.05 + 1e-9, (off, fitted[2])
        np.testing.assert_allclose(fitted[3:], DOOR[3:])  # size and yaw kept
        assert abs(fitted[1] - DOOR[1]) < 1e-9  # never moved up or down


def test_other_classes_low_scores_and_a_door_already_in_place_are_left_as_they_are() -> None:
    off = DOOR.copy()
    off[2] -= 0.2
    boxes = np.stack([off, off, DOOR])
    fitted = _fit(boxes, [CHAIR_IDX, DOOR_IDX, DOOR_IDX], [0.9, MIN_SCORE / 2, 0.9])
    np.testing.assert_allclose(fitted, boxes)
    assert REACH_M >= 0.2  # the offsets above are within the search
