"""a3d.runtime.postprocess.depth_support: how much of the depth in a detection's 2D box its 3D box
holds, and the score it moves."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.postprocess.depth_support import (
    MIN_SCORE,
    SUPPORT_REFERENCE,
    box_points,
    depth_support,
    rescored,
    sample_depth,
    supported_scores,
)
from a3d.runtime.structures.geometry import Intrinsics

K = Intrinsics(100.0, 100.0, 80.0, 60.0)
BLOCK = (slice(40, 100), slice(60, 110))  # rows, columns of a block's face at 2 m, a wall at 4 m
HELD = [0.09, 0.19, 2.1, 1.0, 0.3, 1.2, 0.0]  # holds the face: x -0.4..0.58, y -0.4..0.78, z 2


def _depth() -> np.ndarray:
    depth = np.full((120, 160), 4.0)
    depth[BLOCK] = 2.0
    return depth


def test_a_box_that_holds_its_pixels_has_full_support_and_a_misplaced_one_none():
    boxes2d = np.array([[60, 40, 109, 99]] * 2, float)  # the face's pixels exactly
    behind = [*HELD[:2], 3.0, *HELD[3:]]  # the same box a metre further: the wall's gap
    support = depth_support(sample_depth(_depth(), K, np.eye(3)), boxes2d, np.array([HELD, behind]))
    assert support.tolist() == [1.0, 0.0]


def test_support_is_the_share_of_the_box_pixels_in_the_3d_box():
    depth = _depth()
    boxes2d = np.array([[50, 30, 119, 109]], float)  # the face and a margin of wall
    support = depth_support(sample_depth(depth, K, np.eye(3)), boxes2d, np.array([HELD]))[0]
    window = depth[30:110:2, 50:120:2]  # STRIDE 2, pixel centres from the box's first on
    assert support == pytest.approx((window == 2.0).mean())
    assert 0.4 < support < 0.7


def test_a_2d_box_without_depth_has_no_support():
    depth = _depth()
    depth[BLOCK] = 0.0
    boxes2d = np.array([[60, 40, 109, 99]], float)
    assert depth_support(sample_depth(depth, K, np.eye(3)), boxes2d, np.array([HELD])).tolist() == [0.0]


def test_scores_move_with_support_about_the_reference():
    scores = np.full(3, 0.4)
    moved = supported_scores(scores, np.array([0.0, SUPPORT_REFERENCE, 1.0]))
    assert moved[1] == pytest.approx(0.4)
    assert moved[0] < 0.4 < moved[2] and (0 < moved).all() and (moved < 1).all()
    ranked = supported_scores(np.array([0.9, 0.2]), np.array([0.0, 1.0]))
    assert ranked[0] > ranked[1]  # evidence, not a gate: a sure detection stays ahead


def test_scores_under_the_floor_keep_their_value_and_the_rest_are_moved():
    boxes2d = np.array([[60, 40, 109, 99]] * 2, float)
    behind = [*HELD[:2], 3.0, *HELD[3:]]
    scores = np.array([MIN_SCORE / 2, 0.3])
    moved = rescored(scores, sample_depth(_depth(), K, np.eye(3)), boxes2d, np.array([behind, behind]))
    assert moved[0] == pytest.approx(scores[0]) and moved[1] == pytest.approx(supported_scores(0.3, 0.0))


def test_a_boxs_samples_are_gathered_once_a_frame_and_shared_read_only() -> None:
    sampled = sample_depth(_depth(), K, np.eye(3))
    boxes2d = np.array([[55.0, 35.0, 115.0, 105.0], [0.0, 0.0, 20.0, 20.0]])
    first = box_points(sampled, boxes2d)
    again = box_points(sampled, boxes2d[::-1])
    assert again[1] is first[0] and again[0] is first[1]  # the same arrays, whichever step asks
    assert set(np.round(first[0][:, 2], 6)) == {2.0, 4.0}  # the block's face and the wall round it
    with pytest.raises(ValueError, match="read-only"):
        first[0][0, 0] = 0.0  # no step can change what the next one reads
