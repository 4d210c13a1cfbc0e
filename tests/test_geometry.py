"""Camera model, gravity rotation, 7-vector <-> corners, flips, projection to 2D, 2D IoU, context
boxes and NMS: known answers, round trips and independent references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.structures.geometry import (
    BOX_EDGES,
    NEAR_PLANE_M,
    NYU_CROP_INTRINSICS,
    NYU_CROP_SIZE,
    Intrinsics,
    backproject,
    backproject_depth,
    batched_nms_2d,
    box_area_2d,
    box_corners_camera,
    box_corners_tilt,
    box_edges_clipped,
    boxes_from_corners_tilt,
    boxes_from_pixel_bounds,
    canonical_boxes,
    check_rotation,
    context_boxes,
    depth_seen_at,
    evenly_spread,
    flip_boxes_2d,
    flip_boxes_3d,
    flip_intrinsics,
    flip_rtilt,
    iou_2d,
    iou_3d,
    is_rotation,
    nms_2d,
    pitch_roll_from_rtilt,
    project_boxes_to_2d,
    project_points,
    rtilt_from_pitch_roll,
    wrap_half_pi,
)

K = NYU_CROP_INTRINSICS
H, W = NYU_CROP_SIZE
TILTED = rtilt_from_pitch_roll(math.radians(-20.0), math.radians(3.0))


def random_boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    centres = rng.uniform([-1.5, -0.5, 1.5], [1.5, 1.0, 5.0], (n, 3))
    return np.column_stack([centres, rng.uniform(0.2, 2.0, (n, 3)), rng.uniform(-3.0, 3.0, n)])


# ----------------------------------------------------------------------------- intrinsics, projection


def test_nyu_crop_intrinsics_are_the_spec_values():
    assert NYU_CROP_SIZE == (427, 561)
    np.testing.assert_allclose(
        K.matrix(), [[518.857901, 0, 285.582449], [0, 519.469611, 209.736166], [0, 0, 1]], rtol=0, atol=1e-9
    )


def test_intrinsics_dict_round_trip_and_errors():
    k = Intrinsics(fx=500, fy=501.5, cx=320.25, cy=240)
    assert Intrinsics.from_dict(k.to_dict()) == k
    assert Intrinsics.from_dict({**k.to_dict(), "note": "extra keys are ignored"}) == k
    assert Intrinsics.from_matrix(k.matrix()) == k
    assert isinstance(k.fx, float)
    with pytest.raises(InputError, match="missing cy"):
        Intrinsics.from_dict({"fx": 1, "fy": 1, "cx": 1})
    with pytest.raises(InputError, match="positive"):
        Intrinsics(fx=-500, fy=500, cx=1, cy=1)
    with pytest.raises(InputError, match="not finite"):
        Intrinsics(fx=500, fy=500, cx=float("nan"), cy=1)
    with pytest.raises(InputError, match="must be a number"):
        Intrinsics.from_dict({"fx": "500", "fy": 1, "cx": 1, "cy": 1})


def test_backprojection_matches_the_readme_formula_and_projection_inverts_it():
    u, v, z = np.array([0.0, 100.0, 560.0]), np.array([0.0, 200.0, 426.0]), np.array([1.0, 2.5, 4.0])
    p = backproject(u, v, z, K)
    np.testing.assert_allclose(p[1], [(100 - K.cx) * 2.5 / K.fx, (200 - K.cy) * 2.5 / K.fy, 2.5], rtol=1e-15)
    np.testing.assert_allclose(project_points(p, K), [[0, 0], [100, 200], [560, 426]], atol=1e-10)
    np.testing.assert_allclose(project_points(p, K.matrix()), project_points(p, K), rtol=0, atol=0)


def test_backproject_depth_uses_columns_as_u_and_rows_as_v():
    depth = np.zeros((4, 6), np.float32)
    depth[3, 5] = 2.0
    cloud = backproject_depth(depth, Intrinsics(fx=2.0, fy=4.0, cx=1.0, cy=2.0))
    assert cloud.shape == (4, 6, 3)
    np.testing.assert_allclose(cloud[3, 5], [(5 - 1) * 2 / 2, (3 - 2) * 2 / 4, 2.0])
    assert np.all(cloud[:3] == 0)


def test_project_points_refuses_points_behind_the_camera():
    with pytest.raises(InputError, match="z <= 0"):
        project_points(np.array([[0.0, 0.0, 1.0], [0.1, 0.0, -1.0]]), K)


# ----------------------------------------------------------------------------- gravity rotation


def test_rtilt_is_rx_times_rz_and_round_trips():
    pitch, roll = math.radians(-23.0), math.radians(4.5)
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    r_x = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    expected = r_x @ np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    np.testing.assert_allclose(rtilt_from_pitch_roll(pitch, roll), expected, atol=1e-15)
    for p in np.radians([-80, -35, -10, 0, 5, 40]):
        for r in np.radians([-30, -5, 0, 2, 5]):
            assert pitch_roll_from_rtilt(rtilt_from_pitch_roll(p, r)) == pytest.approx((p, r), abs=1e-12)


def test_a_camera_looking_down_has_negative_pitch():
    """Camera pitched 20 deg down: gravity is (0, cos 20, sin 20) in its frame, +y in the tilt frame."""
    a = math.radians(20.0)
    R = rtilt_from_pitch_roll(-a, 0.0)
    np.testing.assert_allclose(R @ [0.0, math.cos(a), math.sin(a)], [0, 1, 0], atol=1e-15)


def test_rotation_checks():
    assert is_rotation(TILTED) and is_rotation(np.eye(3))
    assert not is_rotation(np.diag([-1.0, 1.0, 1.0]))  # a reflection
    assert not is_rotation(2 * np.eye(3))
    assert not is_rotation(np.full((3, 3), np.nan))
    assert not is_rotation(np.eye(4))
    np.testing.assert_array_equal(check_rotation(TILTED.tolist(), "x"), TILTED)
    with pytest.raises(InputError, match=r"^meta.json R_tilt: not a proper rotation"):
        check_rotation(np.diag([1.0, 1.0, -1.0]), "meta.json R_tilt")
    with pytest.raises(InputError, match="3x3"):
        check_rotation(np.eye(2), "R")
    with pytest.raises(InputError, match="NaN"):
        check_rotation(np.full((3, 3), np.inf), "R")
    c, s = math.cos(0.3), math.sin(0.3)
    yawed = TILTED @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    with pytest.raises(InputError, match="yaw"):
        pitch_roll_from_rtilt(yawed)


# ----------------------------------------------------------------------------- 7-vectors


def test_wrap_half_pi():
    t = np.array([0.0, 1.0, math.pi / 2, -math.pi / 2, math.pi, 3.0, -3.0, 7.5, -100.0])
    w = wrap_half_pi(t)
    assert np.all(np.abs(w) <= math.pi / 2)
    np.testing.assert_allclose(np.sin(2 * w), np.sin(2 * t), atol=1e-12)  # same modulo pi
    np.testing.assert_allclose(w[[0, 1, 4, 5, 6]], [0.0, 1.0, 0.0, 3.0 - math.pi, math.pi - 3.0], atol=1e-15)


def test_canonical_boxes_swaps_length_and_width_with_a_quarter_turn():
    b = np.array([[1.0, 2.0, 3.0, 0.5, 2.0, 1.0, 0.3], [0, 0, 3, 2.0, 0.5, 1.0, 2.0]])
    c = canonical_boxes(b)
    np.testing.assert_allclose(c[0], [1, 2, 3, 2.0, 0.5, 1.0, 0.3 + math.pi / 2 - math.pi], atol=1e-15)
    np.testing.assert_allclose(c[1], [0, 0, 3, 2.0, 0.5, 1.0, 2.0 - math.pi], atol=1e-15)
    np.testing.assert_allclose(np.diag(iou_3d(b, c, TILTED)), 1.0, atol=1e-12)


def _reference_corners_tilt(box: np.ndarray, R: np.ndarray) -> np.ndarray:
    """docs/conventions.md corners, one by one, in the order of the authors' calc_corners_tilt.m."""
    x, y, z, l, w, h, t = box
    rot = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    signs = [(1, 1, 1), (-1, 1, 1), (-1, 1, -1), (1, 1, -1)]
    signs += [(sl, -1, sw) for sl, _, sw in signs]
    return np.array([R @ [x, y, z] + rot @ [sl * l / 2, sh * h / 2, sw * w / 2] for sl, sh, sw in signs])


def test_corners_follow_the_spec_formula_and_documented_order():
    rng = np.random.default_rng(0)
    boxes = random_boxes(rng, 25)
    tilt = box_corners_tilt(boxes, TILTED)
    for box, corners in zip(boxes, tilt, strict=True):
        np.testing.assert_allclose(corners, _reference_corners_tilt(box, TILTED), atol=1e-14)
    np.testing.assert_allclose(box_corners_camera(boxes, TILTED), tilt @ TILTED, atol=1e-14)  # R^T p per row
    # 0-3 the lower face (y down), 4-7 the upper one, each running counter-clockwise in (x, z)
    y_centre = (boxes[:, :3] @ TILTED.T)[:, 1]
    np.testing.assert_allclose(tilt[:, :4, 1], (y_centre + boxes[:, 5] / 2)[:, None].repeat(4, 1), atol=1e-14)
    np.testing.assert_allclose(tilt[:, 4:, [0, 2]], tilt[:, :4, [0, 2]], atol=1e-14)
    x, z = tilt[:, :4, 0], tilt[:, :4, 2]
    area = 0.5 * np.sum(x * np.roll(z, -1, 1) - np.roll(x, -1, 1) * z, axis=1)
    np.testing.assert_allclose(area, boxes[:, 3] * boxes[:, 4], rtol=1e-12)
    edge_len = np.linalg.norm(tilt[:, BOX_EDGES[:, 0]] - tilt[:, BOX_EDGES[:, 1]], axis=2)
    np.testing.assert_allclose(edge_len[:, [0, 2, 4, 6]], boxes[:, [3, 3, 3, 3]], atol=1e-13)
    np.testing.assert_allclose(edge_len[:, [1, 3, 5, 7]], boxes[:, [4, 4, 4, 4]], atol=1e-13)
    np.testing.assert_allclose(edge_len[:, 8:], boxes[:, [5, 5, 5, 5]], atol=1e-13)


def test_theta_is_the_angle_from_z_to_the_orientation_vector():
    """theta = 0: the long edge along x; theta = +pi/4: the orientation vector points to +x, +z."""
    box = np.array([[0, 0, 3, 2.0, 1.0, 1.0, 0.0]])
    c = box_corners_tilt(box, np.eye(3))
    np.testing.assert_allclose(c[0, 0] - c[0, 1], [2, 0, 0], atol=1e-15)  # edge 0-1: the long edge
    box[0, 6] = math.pi / 4
    c = box_corners_tilt(box, np.eye(3))
    orient = c[0, 0] - c[0, 3]  # edge 3 -> 0: the short edge, the orientation vector
    assert math.atan2(orient[0], orient[2]) == pytest.approx(math.pi / 4, abs=1e-15)


def test_corners_to_seven_vector_round_trip():
    rng = np.random.default_rng(1)
    boxes = random_boxes(rng, 200)
    boxes[:10, 4] = boxes[:10, 3]  # square footprints
    for R in (np.eye(3), TILTED, rtilt_from_pitch_roll(math.radians(-35), math.radians(-5))):
        back = boxes_from_corners_tilt(box_corners_tilt(boxes, R), R)
        canon = canonical_boxes(boxes)
        np.testing.assert_allclose(back[:, :6], canon[:, :6], atol=1e-12)
        dtheta = wrap_half_pi(back[:, 6] - canon[:, 6])
        np.testing.assert_allclose(dtheta[10:], 0.0, atol=1e-12)
        np.testing.assert_allclose(np.sin(4 * dtheta[:10]), 0.0, atol=1e-12)  # squares: modulo pi/2
        assert np.all(back[:, 3] >= back[:, 4]) and np.all(np.abs(back[:, 6]) <= math.pi / 2)
        np.testing.assert_allclose(np.diag(iou_3d(boxes, back, R)), 1.0, atol=1e-12)


def _vectorize_bboxes_release(corners: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The authors' VectorizeBboxes.m for one box (1-based corner k is corners[k - 1]), in radians."""
    center = (np.linalg.pinv(R) @ corners.T).T.mean(axis=0)
    H = np.linalg.norm(corners[0] - corners[4])
    d12, d14 = np.linalg.norm(corners[0] - corners[1]), np.linalg.norm(corners[0] - corners[3])
    if d12 > d14:
        size, dir_vec = (d12, d14), corners[0] - corners[3]
    else:
        size, dir_vec = (d14, d12), corners[0] - corners[1]
    ang = math.degrees(math.atan2(dir_vec[0], dir_vec[2]))
    ang = ang - 180 if ang > 90 else ang + 180 if ang < -90 else ang
    return np.array([*center, *size, H, math.radians(ang)])


def test_corners_to_seven_vector_matches_the_release_script():
    rng = np.random.default_rng(2)
    boxes = random_boxes(rng, 100)
    corners = box_corners_tilt(boxes, TILTED)
    ours = boxes_from_corners_tilt(corners, TILTED)
    release = np.stack([_vectorize_bboxes_release(c, TILTED) for c in corners])
    np.testing.assert_allclose(ours, release, atol=1e-12)


def test_corner_input_errors():
    with pytest.raises(InputError, match=r"\(N, 8, 3\)"):
        boxes_from_corners_tilt(np.zeros((2, 4, 3)), np.eye(3))
    with pytest.raises(InputError, match="NaN"):
        boxes_from_corners_tilt(np.full((1, 8, 3), np.nan), np.eye(3))
    with pytest.raises(InputError, match="negative size"):
        box_corners_tilt(np.array([[0, 0, 1, -1.0, 1, 1, 0]]), np.eye(3))
    with pytest.raises(InputError, match=r"\(N, 7\)"):
        box_corners_tilt(np.zeros((3, 6)), np.eye(3))


# ----------------------------------------------------------------------------- flips


def test_flipping_twice_is_the_identity():
    rng = np.random.default_rng(3)
    boxes = random_boxes(rng, 20)
    np.testing.assert_array_equal(flip_boxes_3d(flip_boxes_3d(boxes)), boxes)
    np.testing.assert_allclose(flip_rtilt(flip_rtilt(TILTED)), TILTED, atol=0)
    assert flip_intrinsics(flip_intrinsics(K, W), W) == K
    np.testing.assert_allclose(flip_intrinsics(flip_intrinsics(K.matrix(), W), W), K.matrix(), atol=1e-12)
    b2 = rng.uniform(0, 500, (20, 4))
    np.testing.assert_allclose(flip_boxes_2d(flip_boxes_2d(b2, W), W), b2, atol=1e-12)


def test_flip_conventions():
    np.testing.assert_allclose(flip_boxes_2d(np.array([[-0.5, 0, W - 0.5, 10]]), W), [[-0.5, 0, W - 0.5, 10]])
    np.testing.assert_allclose(flip_boxes_2d(np.array([[0, 1, 10, 2]]), 100), [[89, 1, 99, 2]])
    assert flip_intrinsics(K, W).cx == pytest.approx(W - 1 - K.cx)
    pitch, roll = pitch_roll_from_rtilt(TILTED)
    assert pitch_roll_from_rtilt(flip_rtilt(TILTED)) == pytest.approx((pitch, -roll), abs=1e-12)


def test_a_flipped_box_is_the_mirror_image_of_the_box():
    """Corners of the flipped box (flipped R_tilt) are the mirrored corners; its projection with
    the flipped intrinsics is the flipped projection, and a pixel maps to its mirror pixel."""
    rng = np.random.default_rng(4)
    boxes = random_boxes(rng, 30)
    F = np.diag([-1.0, 1.0, 1.0])
    Rf, Kf = flip_rtilt(TILTED), flip_intrinsics(K, W)
    mirrored = box_corners_camera(boxes, TILTED) @ F
    flipped = box_corners_camera(flip_boxes_3d(boxes), Rf)
    # same set of corners (the mirror image swaps the order within each face)
    np.testing.assert_allclose(np.sort(flipped, axis=1), np.sort(mirrored, axis=1), atol=1e-12)
    proj = project_boxes_to_2d(boxes, TILTED, K, (H, W))
    proj_flipped = project_boxes_to_2d(flip_boxes_3d(boxes), Rf, Kf, (H, W))
    np.testing.assert_allclose(proj_flipped, flip_boxes_2d(proj, W), atol=1e-9)
    assert np.count_nonzero(box_area_2d(proj) > 100) > 20
    p = backproject(np.array([17.0]), np.array([33.0]), np.array([2.0]), K)
    np.testing.assert_allclose(project_points(p @ F, Kf), [[W - 1 - 17.0, 33.0]], atol=1e-10)
    # IoU is a property of the pair: unchanged by flipping both
    others = random_boxes(rng, 30)
    np.testing.assert_allclose(
        iou_3d(flip_boxes_3d(boxes), flip_boxes_3d(others), Rf), iou_3d(boxes, others, TILTED), atol=1e-12
    )


# ----------------------------------------------------------------------------- projection to 2D


def test_projection_of_a_box_in_front_is_the_extent_of_its_projected_corners():
    rng = np.random.default_rng(5)
    boxes = random_boxes(rng, 50)
    boxes[:, 2] += 2.0  # wholly in front
    uv = project_points(box_corners_camera(boxes, TILTED), K)
    expected = np.hstack([uv.min(axis=1), uv.max(axis=1)])
    expected[:, [0, 2]] = expected[:, [0, 2]].clip(-0.5, W - 0.5)
    expected[:, [1, 3]] = expected[:, [1, 3]].clip(-0.5, H - 0.5)
    np.testing.assert_allclose(project_boxes_to_2d(boxes, TILTED, K, (H, W)), expected, atol=1e-9)


def test_projection_of_a_box_straddling_the_camera_known_answer():
    """x in [0.01, 0.02], y in [-0.01, 0.01], z in [-1, 1] (R = I): the part in front of the near
    plane z = 0.05 spans x/z in [0.01/1, 0.02/0.05] and y/z in [-0.01/0.05, 0.01/0.05]."""
    box = np.array([[0.015, 0.0, 0.0, 0.01, 2.0, 0.02, 0.0]])  # l along x, w along z
    got = project_boxes_to_2d(box, np.eye(3), K, (H, W))[0]
    near = NEAR_PLANE_M
    expected = [
        K.cx + K.fx * 0.01,
        K.cy - K.fy * 0.01 / near,
        K.cx + K.fx * 0.02 / near,
        K.cy + K.fy * 0.01 / near,
    ]
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_projection_behind_or_around_the_camera_is_finite():
    boxes = np.array(
        [
            [0, 0, -3.0, 1, 1, 1, 0.3],  # wholly behind
            [0, 0, 0.0, 1, 1, 1, 0.3],  # camera inside the box
            [0.2, 0.1, 0.3, 1, 1, 1, 1.0],  # straddling the near plane
            [0, 0, 0.55, 1, 1, 1, 0.0],  # a face exactly on the near plane
            [0, 0, 0.05, 0, 0, 0, 0.0],  # a point on the near plane
            [30.0, 0, 2.0, 1, 1, 1, 0.0],  # in front, far outside the image
        ]
    )
    for R in (np.eye(3), TILTED):
        got = project_boxes_to_2d(boxes, R, K, (H, W))
        assert np.all(np.isfinite(got))
        np.testing.assert_array_equal(got[0], [-0.5, -0.5, -0.5, -0.5])
        assert np.all(got[:, :2] <= got[:, 2:]) and np.all(got >= -0.5)
        assert np.all(got[:, [0, 2]] <= W - 0.5) and np.all(got[:, [1, 3]] <= H - 0.5)
        assert box_area_2d(got[5:6])[0] == 0.0 and got[5, 0] == W - 0.5
    full = project_boxes_to_2d(boxes[1:2], np.eye(3), K, (H, W))
    np.testing.assert_allclose(full, [[-0.5, -0.5, W - 0.5, H - 0.5]])  # camera inside: whole image


def test_edges_clipped_at_the_near_plane():
    box = np.array([[0, 0, 0.0, 1.0, 1.0, 1.0, 0.0]])  # z from -0.5 (corners 2, 3, 6, 7) to 0.5
    seg, valid = box_edges_clipped(box, np.eye(3))
    assert seg.shape == (1, 12, 2, 3) and valid.shape == (1, 12)
    np.testing.assert_array_equal(valid[0], [1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0, 0])
    assert np.all(seg[valid][..., 2] >= NEAR_PLANE_M)
    # the depth edges 1-2, 3-0, 5-6, 7-4 are cut at the near plane
    np.testing.assert_allclose(np.sort(seg[0, [1, 3, 5, 7], :, 2], axis=1), [[NEAR_PLANE_M, 0.5]] * 4)


# ----------------------------------------------------------------------------- 2D boxes


def test_iou_2d_known_values_without_plus_one():
    a = np.array([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 0.0, 0.0]])
    b = np.array([[5, 0, 15, 10], [0, 0, 10, 10], [10, 0, 20, 10], [2.5, 2.5, 5, 5]], dtype=np.float64)
    iou = iou_2d(a, b)
    np.testing.assert_allclose(iou[0], [50 / 150, 1.0, 0.0, 6.25 / 100])
    np.testing.assert_array_equal(iou[1], 0.0)  # empty box: 0, not NaN
    np.testing.assert_allclose(box_area_2d(b), [100, 100, 100, 6.25])
    assert box_area_2d(np.array([[5.0, 5.0, 4.0, 9.0]]))[0] == 0.0
    assert iou_2d(np.zeros((0, 4)), b).shape == (0, 4)


def test_context_boxes_scale_about_the_centre_and_clip():
    got = context_boxes(np.array([[10.0, 10.0, 20.0, 30.0], [-0.5, 400.0, 100.0, 426.5]]), (H, W))
    np.testing.assert_allclose(got[0], [7.5, 5.0, 22.5, 35.0])
    np.testing.assert_allclose(got[1], [-0.5, 393.375, 125.125, 426.5])  # 150.75 x 39.75, clipped
    doubled = context_boxes(np.array([[10.0, 10.0, 20.0, 30.0]]), (H, W), scale=2.0)
    np.testing.assert_allclose(doubled, [[5, 0, 25, 40]])


def _reference_nms(boxes: np.ndarray, scores: np.ndarray, thr: float) -> list[int]:
    """Plain greedy NMS, one pair at a time."""
    order = sorted(range(len(scores)), key=lambda i: (-scores[i], i))
    keep: list[int] = []
    for i in order:
        ok = True
        for j in keep:
            iw = min(boxes[i, 2], boxes[j, 2]) - max(boxes[i, 0], boxes[j, 0])
            ih = min(boxes[i, 3], boxes[j, 3]) - max(boxes[i, 1], boxes[j, 1])
            inter = max(iw, 0.0) * max(ih, 0.0)
            union = (boxes[i, 2] - boxes[i, 0]) * (boxes[i, 3] - boxes[i, 1])
            union += (boxes[j, 2] - boxes[j, 0]) * (boxes[j, 3] - boxes[j, 1]) - inter
            if union > 0 and inter / union > thr:
                ok = False
                break
        if ok:
            keep.append(i)
    return keep


@pytest.mark.parametrize("thr", [0.0, 0.3, 0.5, 0.7])
def test_nms_matches_a_plain_greedy_reference(thr):
    rng = np.random.default_rng(int(thr * 10))
    for _ in range(5):
        n = 150
        xy = rng.uniform(0, 300, (n, 2))
        boxes = np.hstack([xy, xy + rng.uniform(5, 120, (n, 2))])
        scores = np.round(rng.random(n), 2)  # many ties
        assert list(nms_2d(boxes, scores, thr)) == _reference_nms(boxes, scores, thr)


@pytest.mark.parametrize("thr", [0.0, 0.3, 0.7])
def test_nms_large_group_loop_path_matches_the_matrix_path(thr, monkeypatch):
    """Groups above the matrix limit take the plain loop: same kept indices, same order."""
    import a3d.runtime.structures.geometry as geometry

    rng = np.random.default_rng(42)
    xy = rng.uniform(0, 300, (200, 2))
    boxes = np.hstack([xy, xy + rng.uniform(5, 120, (200, 2))])
    scores = np.round(rng.random(200), 2)
    labels = rng.integers(0, 3, 200)
    by_matrix = batched_nms_2d(boxes, scores, labels, thr)
    monkeypatch.setattr(geometry, "_MATRIX_NMS_LIMIT", 0)
    assert list(batched_nms_2d(boxes, scores, labels, thr)) == list(by_matrix)
    assert list(nms_2d(boxes, scores, thr)) == _reference_nms(boxes, scores, thr)


def test_nms_keeps_a_box_exactly_at_the_threshold_and_takes_any_scores():
    boxes = np.array([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 5.0], [0.0, 0.0, 10.0, 4.9]])
    # IoU(0, 1) = 0.5 exactly: kept at 0.5; box 2 has IoU 0.98 with box 1
    assert list(nms_2d(boxes, np.array([0.9, 0.8, 0.7]), 0.5)) == [0, 1]
    assert list(nms_2d(boxes[:2], np.array([0.9, 0.8]), 0.4999)) == [0]
    # zero and negative scores are ordinary scores (cv2.dnn.NMSBoxes would drop them)
    assert list(nms_2d(boxes, np.array([-1.0, 0.0, -2.0]), 0.3)) == [1]
    assert list(nms_2d(boxes, np.array([-1.0, 0.0, -2.0]), 1.0)) == [1, 0, 2]
    assert nms_2d(np.zeros((0, 4)), np.zeros(0), 0.3).shape == (0,)
    with pytest.raises(InputError, match="NaN"):
        nms_2d(boxes, np.array([0.5, np.nan, 0.1]), 0.3)


def test_batched_nms_only_suppresses_within_a_label():
    rng = np.random.default_rng(7)
    n = 300
    xy = rng.uniform(0, 200, (n, 2))
    boxes = np.hstack([xy, xy + rng.uniform(10, 80, (n, 2))])
    scores = rng.random(n)
    labels = rng.integers(0, 5, n)
    got = batched_nms_2d(boxes, scores, labels, 0.3)
    expected = []
    for c in range(5):
        idx = np.flatnonzero(labels == c)
        expected += [idx[k] for k in _reference_nms(boxes[idx], scores[idx], 0.3)]
    assert sorted(got) == sorted(expected)
    assert np.all(np.diff(scores[got]) <= 0)  # by descending score
    with pytest.raises(InputError, match="scores"):
        nms_2d(boxes, scores[:-1], 0.3)


def test_boxes_from_pixel_bounds_run_along_the_outer_pixel_edges() -> None:
    mask = np.zeros((6, 8), bool)
    mask[2:5, 1:7] = True  # rows 2..4, columns 1..6
    v, u = np.nonzero(mask)
    box = boxes_from_pixel_bounds([u.min(), v.min(), u.max(), v.max()])
    np.testing.assert_array_equal(box, [0.5, 1.5, 6.5, 4.5])
    assert (box[2] - box[0], box[3] - box[1]) == (6.0, 3.0)  # width and height count the pixels
    np.testing.assert_array_equal(boxes_from_pixel_bounds(np.zeros((0, 4), int)).shape, (0, 4))


def test_evenly_spread_keeps_at_most_the_limit_spread_over_all() -> None:
    np.testing.assert_array_equal(evenly_spread(np.arange(10), 4), [0, 3, 6, 9])
    np.testing.assert_array_equal(evenly_spread(np.arange(10), 5), [0, 2, 4, 6, 8])
    np.testing.assert_array_equal(evenly_spread(np.arange(3), 5), [0, 1, 2])
    assert evenly_spread(np.zeros((0, 3)), 5).shape == (0, 3)


def test_depth_seen_at_reads_the_map_where_a_point_projects_and_0_where_it_cannot() -> None:
    K = Intrinsics(100.0, 100.0, 39.5, 29.5)  # an 80 x 60 frame, its depth kept every 2nd pixel
    depth = np.arange(40 * 30, dtype=np.float32).reshape(30, 40) / 100 + 1.0
    points = np.array([
        [0.0, 0.0, 2.0],  # the optical axis: pixel (39.5, 29.5), map cell (20, 15) after rounding
        [0.0, 0.0, -2.0],  # behind the camera
        [0.0, 0.0, 0.05],  # ahead, but nearer than near_m
        [5.0, 0.0, 2.0],  # off the frame to the right
    ])  # fmt: skip
    seen = depth_seen_at(points, depth, K, stride=2, near_m=0.1)
    np.testing.assert_allclose(seen, [depth[15, 20], 0.0, 0.0, 0.0])
    assert depth_seen_at(points[None], depth, K, stride=2, near_m=0.1).shape == (1, 4)  # any leading shape
