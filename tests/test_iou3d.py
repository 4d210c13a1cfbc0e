"""3D IoU: known answers, invariances, exact collinear cases, and parity with an independent
half-space reference (scipy) on random overlapping pairs under random gravity rotations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection

from a3d.runtime.structures.geometry import iou_3d, rtilt_from_pitch_roll

TILTED = rtilt_from_pitch_roll(math.radians(-25.0), math.radians(4.0))


def from_tilt(boxes_tilt: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Boxes given by tilt-frame centres, re-expressed with camera-frame centres R^T c."""
    out = np.array(boxes_tilt, dtype=np.float64).reshape(-1, 7).copy()
    out[:, :3] = out[:, :3] @ R  # row-vector form of R^T c
    return out


def random_boxes(rng: np.random.Generator, n: int, spread: float = 0.5, yaw: float = 1.5) -> np.ndarray:
    """n boxes around (0, 0, 3) m, sizes 0.3-2 m, theta in [-yaw, yaw]."""
    centres = rng.normal(0.0, spread, (n, 3)) + np.array([0.0, 0.0, 3.0])
    return np.column_stack([centres, rng.uniform(0.3, 2.0, (n, 3)), rng.uniform(-yaw, yaw, n)])


def shifted(box_tilt: np.ndarray, along: str, d: float) -> np.ndarray:
    """The tilt-frame box moved by d along its own length (l), width (w) or height (h) axis."""
    t = box_tilt[6]
    axis = {"l": (math.cos(t), 0.0, -math.sin(t)), "w": (math.sin(t), 0.0, math.cos(t)), "h": (0.0, 1.0, 0.0)}
    out = np.array(box_tilt, dtype=np.float64)
    out[:3] += d * np.asarray(axis[along])
    return out


# ----------------------------------------------------------------------------- known answers


def test_identical_boxes_have_iou_one():
    rng = np.random.default_rng(1)
    boxes = random_boxes(rng, 20)
    iou = iou_3d(boxes, boxes, TILTED)
    np.testing.assert_allclose(np.diag(iou), 1.0, atol=1e-12)


def test_disjoint_boxes_have_iou_zero():
    a = np.array([0.0, 0.0, 3.0, 1.0, 0.5, 1.0, 0.3])
    far = shifted(a, "l", 5.0)  # side by side, far apart
    above = shifted(a, "h", 1.0001)  # same footprint, vertically disjoint
    touching_h = shifted(a, "h", 1.0)  # sharing a horizontal face
    iou = iou_3d(from_tilt(a, TILTED), from_tilt(np.stack([far, above, touching_h]), TILTED), TILTED)
    assert iou[0, 0] == 0.0 and iou[0, 1] == 0.0
    assert iou[0, 2] < 1e-12  # touching: zero up to the rounding of the two centres


@pytest.mark.parametrize("along, size", [("l", 2.0), ("w", 0.8), ("h", 1.2)])
@pytest.mark.parametrize("d", [0.05, 0.3, 0.79])
def test_shift_along_an_axis_gives_the_analytic_value(along, size, d):
    """Equal boxes shifted by d along their own axis of extent s: IoU = (s - d) / (s + d)."""
    a = np.array([0.4, -0.2, 3.5, 2.0, 0.8, 1.2, 0.7])
    b = shifted(a, along, d)
    iou = iou_3d(from_tilt(a, TILTED), from_tilt(b, TILTED), TILTED)[0, 0]
    assert iou == pytest.approx((size - d) / (size + d), abs=1e-12)


def test_square_footprint_rotated_45_degrees_against_itself():
    """Same centre and height: the footprints meet in a regular octagon of area 2 (sqrt2 - 1) s^2
    (0.8284 of either square), so IoU = 2 (sqrt2 - 1) / (2 - 2 (sqrt2 - 1)) = 1 / sqrt2 = 0.70711."""
    s = 1.3
    a = np.array([[0.2, 0.1, 2.5, s, s, 0.9, 0.1]])
    b = a.copy()
    b[0, 6] += math.pi / 4
    iou = iou_3d(a, b, TILTED)[0, 0]
    assert iou == pytest.approx(1.0 / math.sqrt(2.0), abs=1e-12)
    assert iou == pytest.approx(0.70711, abs=5e-6)
    octagon = 2.0 * (math.sqrt(2.0) - 1.0) * s * s
    assert iou == pytest.approx(octagon / (2 * s * s - octagon), abs=1e-12)


def test_rectangle_against_itself_turned_90_degrees():
    """A 2 x 1 footprint and its 90-degree turn about the same centre meet in a 1 x 1 square."""
    a = np.array([[0.0, 0.0, 3.0, 2.0, 1.0, 1.0, 0.2]])
    b = a.copy()
    b[0, 6] += math.pi / 2
    assert iou_3d(a, b, TILTED)[0, 0] == pytest.approx(1.0 / 3.0, abs=1e-12)


def test_box_inside_box_gives_the_volume_ratio():
    outer = np.array([0.0, 0.0, 3.0, 2.0, 1.5, 1.0, 0.3])
    inner = np.array([0.1, 0.05, 3.1, 0.5, 0.4, 0.3, -0.9])  # rotated, fully inside
    iou = iou_3d(from_tilt(outer, TILTED), from_tilt(inner, TILTED), TILTED)[0, 0]
    assert iou == pytest.approx(0.5 * 0.4 * 0.3 / (2.0 * 1.5 * 1.0), abs=1e-12)


def test_theta_and_theta_minus_pi_are_the_same_box():
    rng = np.random.default_rng(2)
    a = random_boxes(rng, 30)
    b = a.copy()
    b[:, 6] -= math.pi
    others = random_boxes(rng, 30, yaw=3.0)
    np.testing.assert_allclose(np.diag(iou_3d(a, b, TILTED)), 1.0, atol=1e-12)
    np.testing.assert_allclose(iou_3d(a, others, TILTED), iou_3d(b, others, TILTED), atol=1e-12)
    assert np.count_nonzero(iou_3d(a, others, TILTED) > 0.05) > 30  # the comparison is not all zeros


def test_swapping_length_and_width_with_a_quarter_turn_is_the_same_box():
    rng = np.random.default_rng(3)
    a = random_boxes(rng, 30)
    b = a.copy()
    b[:, [3, 4]] = a[:, [4, 3]]
    b[:, 6] += math.pi / 2
    others = random_boxes(rng, 30, yaw=3.0)
    np.testing.assert_allclose(np.diag(iou_3d(a, b, TILTED)), 1.0, atol=1e-12)
    np.testing.assert_allclose(iou_3d(a, others, TILTED), iou_3d(b, others, TILTED), atol=1e-12)


def test_iou_does_not_depend_on_the_camera_pose_of_the_same_tilt_frame_boxes():
    """The same tilt-frame boxes seen from cameras with different R_tilt: one IoU matrix."""
    rng = np.random.default_rng(4)
    n = 40
    a = random_boxes(rng, n, spread=0.6)
    b = a + np.column_stack([rng.normal(0, 0.3, (n, 3)), np.zeros((n, 3)), rng.normal(0, 0.5, n)])
    reference = iou_3d(a, b, np.eye(3))  # tilt frame = camera frame
    assert np.count_nonzero(reference > 0.1) >= n
    for pitch, roll in [(-35, -5), (-10, 3), (5, 5), (-22.5, 0.7)]:
        R = rtilt_from_pitch_roll(math.radians(pitch), math.radians(roll))
        np.testing.assert_allclose(iou_3d(from_tilt(a, R), from_tilt(b, R), R), reference, atol=1e-12)


@pytest.mark.parametrize("theta_deg", [0.0, 17.0, 30.0, 45.0, 60.0, 89.0, 90.0, -33.3, -90.0])
def test_collinear_edges_give_the_exact_value(theta_deg):
    """Same theta, shifted along an edge (the footprints share the lines of two edges), under a
    tilted R_tilt: the exact value, where cv2.rotatedRectangleIntersection can lose a whole piece."""
    a = np.array([0.3, 0.1, 3.0, 2.0, 1.0, 0.8, math.radians(theta_deg)])
    cases = [("l", d, (2.0 - d) / (2.0 + d)) for d in (0.1, 0.7, 1.3, 1.999)]
    cases += [("w", d, (1.0 - d) / (1.0 + d)) for d in (0.25, 0.5)]
    cases += [("l", -0.7, 1.3 / 2.7), ("l", 2.0, 0.0), ("w", 1.0, 0.0), ("w", -1.0, 0.0)]  # last three touch
    others = from_tilt(np.stack([shifted(a, along, d) for along, d, _ in cases]), TILTED)
    iou = iou_3d(from_tilt(a, TILTED), others, TILTED)[0]
    np.testing.assert_allclose(iou, [v for _, _, v in cases], atol=1e-12)
    np.testing.assert_allclose(iou_3d(others, from_tilt(a, TILTED), TILTED)[:, 0], iou, atol=1e-12)


def test_collinear_edges_with_different_sizes_give_the_exact_value():
    """A narrower box sliding along the long edge of a wider one (one shared edge line)."""
    a = np.array([0.0, 0.0, 3.0, 2.0, 1.0, 1.0, 0.5])
    b = a.copy()
    b[4] = 0.4
    b = shifted(shifted(b, "w", 0.3), "l", 0.5)  # its +w edge lies on a's +w edge line
    inter = 1.5 * 0.4 * 1.0
    iou = iou_3d(from_tilt(a, TILTED), from_tilt(b, TILTED), TILTED)[0, 0]
    assert iou == pytest.approx(inter / (2.0 + 0.8 - inter), abs=1e-12)


def test_zero_volume_boxes_and_empty_inputs():
    a = np.array([[0.0, 0.0, 3.0, 1.0, 1.0, 1.0, 0.0], [0.0, 0.0, 3.0, 1.0, 0.0, 1.0, 0.0]])
    iou = iou_3d(a, a, TILTED)
    np.testing.assert_array_equal(iou, [[1.0, 0.0], [0.0, 0.0]])
    assert iou_3d(np.zeros((0, 7)), a, TILTED).shape == (0, 2)
    assert iou_3d(a, np.zeros((0, 7)), TILTED).shape == (2, 0)


def test_many_pairs_are_chunked_without_changing_the_result():
    """More candidate pairs than one clipping chunk gives the same values as small calls."""
    rng = np.random.default_rng(5)
    a = random_boxes(rng, 150, spread=0.3, yaw=2.0)
    full = iou_3d(a, a, TILTED)
    assert np.count_nonzero(full) > 8192
    rows = [iou_3d(a[i : i + 1], a, TILTED)[0] for i in range(0, 150, 37)]
    np.testing.assert_allclose(full[0:150:37], np.stack(rows), rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------- independent reference


def _reference_corners_camera(box: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The 8 camera-frame corners straight from docs/conventions.md, one at a time (no shared code)."""
    x, y, z, l, w, h, t = box
    rot_y = np.array([[math.cos(t), 0.0, math.sin(t)], [0.0, 1.0, 0.0], [-math.sin(t), 0.0, math.cos(t)]])
    centre_tilt = R @ np.array([x, y, z])
    corners = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                local = np.array([sx * l / 2, sy * h / 2, sz * w / 2])
                corners.append(R.T @ (centre_tilt + rot_y @ local))
    return np.array(corners)


def _halfspaces(corners: np.ndarray) -> np.ndarray:
    """The 6 face half-spaces [n, -n.p] (n.x - n.p <= 0 inside) of a box from its 8 corners."""
    centre = corners.mean(axis=0)
    rows = []
    # corners are ordered by (sx, sy, sz) bits: axis k runs between indices differing in bit 2 - k
    for bit in (4, 2, 1):
        idx_lo = [i for i in range(8) if not i & bit]
        idx_hi = [i for i in range(8) if i & bit]
        axis = corners[idx_hi].mean(axis=0) - corners[idx_lo].mean(axis=0)
        half = np.linalg.norm(axis) / 2.0
        n = axis / np.linalg.norm(axis)
        rows.append(np.append(n, -(n @ centre) - half))
        rows.append(np.append(-n, (n @ centre) - half))
    return np.array(rows)


def _reference_iou(box_a: np.ndarray, box_b: np.ndarray, R: np.ndarray) -> float | None:
    """IoU from the volume of the intersection polyhedron of the two boxes' 12 half-spaces.

    None when the intersection is too thin for qhull to be trusted (Chebyshev radius < 1e-6).
    """
    hs = np.vstack([_halfspaces(_reference_corners_camera(box, R)) for box in (box_a, box_b)])
    norms = np.linalg.norm(hs[:, :3], axis=1)
    # Chebyshev centre: max r s.t. n.x + r |n| <= -offset
    res = linprog(
        c=[0, 0, 0, -1],
        A_ub=np.column_stack([hs[:, :3], norms]),
        b_ub=-hs[:, 3],
        bounds=[(None, None)] * 3 + [(0, None)],
        method="highs",
    )
    if res.status == 2:  # infeasible: the boxes do not meet
        return 0.0
    assert res.status == 0, res.message
    if res.x[3] < 1e-6:
        return 0.0 if res.x[3] == 0.0 else None
    inter = ConvexHull(HalfspaceIntersection(hs, res.x[:3]).intersections).volume
    va, vb = np.prod(box_a[3:6]), np.prod(box_b[3:6])
    return inter / (va + vb - inter)


def test_agrees_with_an_independent_halfspace_reference_on_random_pairs():
    """1000 pairs (20 camera poses x 50), mostly overlapping, to 1e-9: every pair (i, i) is a
    random box and a random perturbation of it, plus 10 unrelated pairs (i, j) per pose."""
    rng = np.random.default_rng(20240611)
    checked = overlapping = 0
    for _ in range(20):
        R = rtilt_from_pitch_roll(math.radians(rng.uniform(-35, 5)), math.radians(rng.uniform(-5, 5)))
        n = 50
        centres = rng.uniform([-1.5, -0.8, 1.0], [1.5, 0.8, 5.0], (n, 3))
        a = np.column_stack([centres, rng.uniform(0.1, 2.5, (n, 3)), rng.uniform(-1.6, 1.6, n)])
        b = a.copy()
        b[:, :3] += rng.normal(0, 0.35, (n, 3)) * a[:, 3:6].mean(axis=1, keepdims=True)
        b[:, 3:6] *= rng.uniform(0.5, 1.5, (n, 3))
        b[:, 6] = np.where(rng.random(n) < 0.3, a[:, 6], rng.uniform(-3.2, 3.2, n))  # 30% same yaw
        iou = iou_3d(a, b, R)
        pairs = [(i, i) for i in range(n)] + [tuple(p) for p in rng.integers(0, n, (10, 2))]
        for i, j in pairs:
            ref = _reference_iou(a[i], b[j], R)
            if ref is None:  # a sliver: our value must be tiny too
                assert iou[i, j] < 1e-5
                continue
            assert iou[i, j] == pytest.approx(ref, abs=1e-9), (i, j, a[i], b[j])
            checked += 1
            overlapping += ref > 0.05
    assert checked >= 1000 and overlapping >= 600
