"""Property-based tests (hypothesis): random boxes, rotations and intrinsics. Every geometry call
either returns finite values or raises InputError (a clear one-line ValueError); IoUs are
symmetric, in [0, 1], 1 for a box with itself and unchanged by the box's equivalent forms."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from a3d.runtime.errors import InputError
from a3d.runtime.postprocess import box_coder
from a3d.runtime.structures import geometry
from a3d.runtime.structures.geometry import (
    Intrinsics,
    box_corners_tilt,
    boxes_from_corners_tilt,
    canonical_boxes,
    iou_2d,
    iou_3d,
    nms_2d,
    project_boxes_to_2d,
    rtilt_from_pitch_roll,
)

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

angles = st.floats(-math.pi, math.pi, allow_nan=False)


@st.composite
def rotations(draw) -> np.ndarray:
    """R_x R_z gravity rotations, or any rotation at all (from a unit quaternion)."""
    if draw(st.booleans()):
        return rtilt_from_pitch_roll(draw(angles), draw(angles))
    q = np.array(draw(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4)))
    assume(np.linalg.norm(q) > 0.1)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def boxes3d(min_size: float = 0.0, max_n: int = 6):
    """(N, 7) boxes: centres within 20 m, sizes up to 10 m (zero allowed), any yaw."""
    centre = st.floats(-20, 20, allow_nan=False)
    size = st.floats(min_size, 10, allow_nan=False)
    yaw = st.floats(-10, 10, allow_nan=False)
    box = st.tuples(centre, centre, centre, size, size, size, yaw)
    return st.lists(box, min_size=1, max_size=max_n).map(lambda rows: np.array(rows, dtype=np.float64))


def boxes2d(max_n: int = 12):
    corner = st.floats(-100, 800, allow_nan=False)
    extent = st.floats(0, 400, allow_nan=False)
    box = st.tuples(corner, corner, extent, extent).map(lambda b: (b[0], b[1], b[0] + b[2], b[1] + b[3]))
    return st.lists(box, min_size=1, max_size=max_n).map(lambda rows: np.array(rows, dtype=np.float64))


intrinsics = st.builds(
    Intrinsics,
    fx=st.floats(1e-2, 1e5),
    fy=st.floats(1e-2, 1e5),
    cx=st.floats(-1e4, 1e4),
    cy=st.floats(-1e4, 1e4),
)
image_sizes = st.tuples(st.integers(1, 2000), st.integers(1, 2000))


@SETTINGS
@given(boxes3d(min_size=1e-3), boxes3d(min_size=1e-3), rotations())
def test_iou_3d_is_symmetric_and_in_the_unit_interval(a, b, R):
    # Boxes of at least a millimetre a side: hypothesis found 1e-8 m wide footprints whose clipped
    # intersection, divided by a union of ~1e-16 m^3, differs by 7e-8 between the two orders.
    iou = iou_3d(a, b, R)
    assert iou.shape == (len(a), len(b))
    assert np.all(np.isfinite(iou)) and np.all(iou >= 0) and np.all(iou <= 1)
    np.testing.assert_allclose(iou, iou_3d(b, a, R).T, atol=1e-9)


@SETTINGS
@given(boxes3d(min_size=0.01), rotations())
def test_a_box_in_any_of_its_forms_has_iou_one_with_itself(a, R):
    canon = canonical_boxes(a)
    assert np.all(canon[:, 3] >= canon[:, 4]) and np.all(np.abs(canon[:, 6]) <= math.pi / 2)
    shifted_yaw = a.copy()
    shifted_yaw[:, 6] -= math.pi
    for other in (a, canon, shifted_yaw):
        np.testing.assert_allclose(np.diag(iou_3d(a, other, R)), 1.0, atol=1e-9)


@SETTINGS
@given(boxes3d(min_size=0.01), rotations())
def test_corners_round_trip_to_the_same_box(a, R):
    back = boxes_from_corners_tilt(box_corners_tilt(a, R), R)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(back[:, :3], a[:, :3], atol=1e-9)
    np.testing.assert_allclose(np.sort(back[:, 3:5], axis=1), np.sort(a[:, 3:5], axis=1), rtol=1e-9)
    np.testing.assert_allclose(np.diag(iou_3d(a, back, R)), 1.0, atol=1e-9)


@SETTINGS
@given(boxes3d(), rotations(), intrinsics, image_sizes)
def test_projection_is_finite_and_inside_the_image(boxes, R, K, size):
    got = project_boxes_to_2d(boxes, R, K, size)
    H, W = size
    assert np.all(np.isfinite(got))
    assert np.all(got[:, :2] <= got[:, 2:]) and np.all(got >= -0.5)
    assert np.all(got[:, [0, 2]] <= W - 0.5) and np.all(got[:, [1, 3]] <= H - 0.5)


@SETTINGS
@given(boxes2d(), boxes2d())
def test_iou_2d_is_symmetric_and_in_the_unit_interval(a, b):
    iou = iou_2d(a, b)
    assert np.all(np.isfinite(iou)) and np.all(iou >= 0) and np.all(iou <= 1 + 1e-12)
    np.testing.assert_array_equal(iou, iou_2d(b, a).T)


@SETTINGS
@given(boxes2d(max_n=30), st.floats(0, 1), st.randoms(use_true_random=False))
def test_nms_result_is_a_valid_greedy_suppression(boxes, thr, rnd):
    scores = np.array([rnd.random() for _ in range(len(boxes))])
    keep = nms_2d(boxes, scores, thr)
    iou = iou_2d(boxes, boxes)
    assert np.all(np.diff(scores[keep]) <= 0)
    kept_iou = iou[np.ix_(keep, keep)]
    assert np.all(kept_iou[~np.eye(len(keep), dtype=bool)] <= thr)  # kept boxes do not suppress each other
    for i in np.setdiff1d(np.arange(len(boxes)), keep):  # each dropped box has a kept, better suppressor
        better = keep[(scores[keep] > scores[i]) | ((scores[keep] == scores[i]) & (keep < i))]
        assert np.any(iou[i, better] > thr)


@SETTINGS
@given(boxes3d(min_size=0.2), boxes3d(min_size=0.2))
def test_box_coder_round_trip(p, g):
    """Sizes 0.2-10 m: scale ratios within decoding's clamp (62.5)."""
    n = min(len(p), len(g))
    p, g = p[:n], g[:n]
    np.testing.assert_allclose(box_coder.decode_3d(p, box_coder.encode_3d(p, g)), g, rtol=1e-9, atol=1e-9)


# ----------------------------------------------------------------------------- anything at all

any_float = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _finite_or_input_error(fn, *args) -> None:
    """The call returns only finite numbers, or raises InputError; anything else fails the test."""
    try:
        out = fn(*args)
    except InputError as e:
        assert "\n" not in str(e) and str(e)
        return
    for value in out if isinstance(out, tuple) else (out,):
        assert np.all(np.isfinite(np.asarray(value, dtype=np.float64))), fn.__name__


@SETTINGS
@given(
    hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.sampled_from([4, 7])), elements=any_float),
    hnp.arrays(np.float64, (3, 3), elements=any_float),
    st.tuples(st.integers(-5, 3000), st.integers(-5, 3000)),
    st.floats(allow_nan=True, allow_infinity=True),
    hnp.arrays(np.float64, st.tuples(st.integers(0, 3), st.just(8), st.just(3)), elements=any_float),
)
def test_arbitrary_values_give_finite_results_or_a_clear_error(arr, R, size, x, corners):
    g = geometry
    calls = [
        (g.iou_3d, arr, arr, R),
        (g.box_corners_camera, arr, R),
        (g.canonical_boxes, arr),
        (g.flip_boxes_3d, arr),
        (g.iou_2d, arr, arr),
        (g.context_boxes, arr, size, x),
        (g.nms_2d, arr, arr[:, 0], x),
        (g.flip_boxes_2d, arr, size[1]),
        (g.project_boxes_to_2d, arr, R, Intrinsics(500.0, 500.0, 320.0, 240.0), size),
        (g.check_rotation, R, "R"),
        (g.pitch_roll_from_rtilt, R),
        (g.wrap_half_pi, arr),
        (g.boxes_from_corners_tilt, corners, R),
        (g.boxes_from_corners_tilt, corners, np.eye(3)),
        (box_coder.decode_3d, arr, arr),
        (box_coder.encode_3d, arr, arr),
        (box_coder.encode_2d, arr, arr),
        (box_coder.decode_2d, arr, arr),
        (g.backproject, arr, arr, arr, Intrinsics(500.0, 500.0, 320.0, 240.0)),
        (g.rtilt_from_pitch_roll, x, 0.1),
    ]
    for fn, *args in calls:
        _finite_or_input_error(fn, *args)
