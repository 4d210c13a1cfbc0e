"""Fitting a gravity-aligned box to the points inside a user's rough box (a3d.runtime.mapping.box_fit)."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.mapping.box_fit import (
    DepthView,
    fit_box,
    fitted_box,
    floor_level,
    seen_free,
    world_cloud,
    world_points,
)
from a3d.runtime.mapping.world import box_differences
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics, box_corners_camera
from a3d.runtime.structures.pose import invert_pose, make_pose

TRUE = np.array([1.0, -0.45, 3.0, 1.2, 0.6, 0.9, 0.4])  # a world box (y down: its top at y = -0.9)


def surface_points(box: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points on the box's faces (what depth sees of an object), from its 8 corners."""
    c = box_corners_camera(box[None], np.eye(3))[0]
    faces = [(0, 1, 3), (4, 5, 7), (0, 1, 4), (3, 2, 7), (0, 3, 4), (1, 2, 5)]  # origin, two edges
    out = []
    for o, a, b in faces:
        u, v = rng.random((n, 1)), rng.random((n, 1))
        out.append(c[o] + u * (c[a] - c[o]) + v * (c[b] - c[o]))
    return np.concatenate(out)


def test_the_fit_recovers_the_box_from_a_rough_one_among_clutter() -> None:
    rng = np.random.default_rng(0)
    clutter = rng.uniform([-2, -2, 0], [4, 0, 6], (3000, 3))
    clutter = clutter[np.abs(clutter[:, 0] - TRUE[0]) + np.abs(clutter[:, 2] - TRUE[2]) > 1.6]  # not on it
    points = np.vstack([surface_points(TRUE, 400, rng), clutter])
    rough = TRUE + np.array([0.08, -0.05, -0.06, 0.15, 0.1, 0.1, 0.12])  # off by a hand's width
    fitted = fit_box(points, rough)
    assert box_differences(fitted[None], TRUE[None])[0] < 0.02
    assert fitted[3] >= fitted[4] and abs(fitted[6]) <= np.pi / 2


def test_a_rough_box_around_nothing_is_one_line() -> None:
    with pytest.raises(InputError, match=r"^rough box \[.*\]: 0 points inside, need 20"):
        fit_box(np.zeros((0, 3)), TRUE)


def test_world_points_are_each_posed_frames_depth_moved_into_the_world() -> None:
    K = Intrinsics(50.0, 50.0, 15.5, 11.5)
    depth = np.full((24, 32), 2.0, np.float32)
    depth[0, 0] = 0.0  # no measurement: left out
    pose = make_pose(np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]), [1.0, -1.5, 0.5])
    color = np.zeros((24, 32, 3), np.uint8)
    frames = [Frame("a", color, depth, K, pose=pose), Frame("b", color, depth, K)]  # b has no pose
    points = world_points(frames, stride=1)
    assert points.shape == (24 * 32 - 1, 3)
    views = world_cloud(frames, stride=2).views  # the posed frame's depth, every 2nd pixel
    assert len(views) == 1 and views[0].depth.shape == (12, 16) and views[0].stride == 2
    # every point is 2 m in front of the camera along its optical axis (world +x after the turn)
    np.testing.assert_allclose(points[:, 0], 1.0 + 2.0, atol=1e-9)


def test_the_floor_round_an_object_is_left_out_and_its_box_stands_on_the_floor() -> None:
    rng = np.random.default_rng(1)
    standing = TRUE.copy()
    standing[1] = -standing[5] / 2  # its bottom on the floor, y = 0
    floor = np.column_stack(
        [rng.uniform(-2, 4, 20000), rng.normal(0, 0.005, 20000), rng.uniform(0, 6, 20000)]
    )
    object_points = surface_points(standing, 400, rng)
    points = np.vstack([object_points[object_points[:, 1] < -0.05], floor])  # the sensor misses its foot
    rough = standing + np.array([0.05, 0.06, -0.05, 0.1, 0.1, 0.1, 0.1])  # its bottom 1 cm below the floor
    assert abs(floor_level(points)) < 0.01
    fitted = fit_box(points, rough, floor_y=floor_level(points))
    assert box_differences(fitted[None], standing[None])[0] < 0.02
    assert box_differences(fit_box(points, rough)[None], standing[None])[0] > 0.05  # the floor taken in


def test_a_wall_the_margin_reaches_into_is_left_out() -> None:
    rng = np.random.default_rng(2)
    standing = TRUE.copy()
    standing[1] = -standing[5] / 2
    n = 20000
    floor = np.column_stack([rng.uniform(-2, 4, n), rng.normal(0, 0.005, n), rng.uniform(0, 6, n)])
    wall_x = TRUE[0] + 0.75  # 12 cm beyond the box's farthest corner along x
    wall = np.column_stack([np.full(8000, wall_x), rng.uniform(-2, 0, 8000), rng.uniform(0, 6, 8000)])
    points = np.vstack([surface_points(standing, 400, rng), floor, wall])
    rough = standing + np.array([0.06, 0.0, 0.05, 0.1, 0.1, 0.05, 0.1])  # its margin reaches the wall
    fitted = fit_box(points, rough, floor_y=floor_level(points))
    assert box_differences(fitted[None], standing[None])[0] < 0.02


def test_the_sensors_stray_depth_beyond_a_surface_does_not_widen_the_box() -> None:
    rng = np.random.default_rng(3)
    points = surface_points(TRUE, 2000, rng)
    points += rng.normal(0, 0.005, points.shape)  # the noise of depth fused from many views
    points[rng.choice(len(points), 60, replace=False)] += rng.normal(0, 0.06, (60, 3))  # and strays
    rough = TRUE + np.array([0.05, -0.04, 0.05, 0.1, 0.1, 0.1, 0.1])
    fitted = fit_box(points, rough)
    assert box_differences(fitted[None], TRUE[None])[0] < 0.03  # the noise's own centimetre a side
    spread = np.ptp(points[:, 1][np.abs(points[:, 1] - TRUE[1]) < 0.6])  # the points' own height range
    assert spread > TRUE[5] + 0.08  # the strays alone would have made the box that much taller


def test_a_face_where_a_neighbour_runs_on_to_the_margins_edge_is_the_rough_boxs() -> None:
    rng = np.random.default_rng(4)
    box = np.array([1.0, -1.05, 3.0, 0.4, 0.3, 0.3, 0.0])  # a box on a counter, against the wall behind it
    n = 20000
    top = np.column_stack([rng.uniform(0, 2, n), rng.normal(-0.9, 0.003, n), rng.uniform(2.6, 3.15, n)])
    wall = np.column_stack([rng.uniform(0, 2, n), rng.uniform(-2.5, -0.9, n), rng.normal(3.15, 0.003, n)])
    on_box = surface_points(box, 500, rng)
    points = np.vstack([on_box[on_box[:, 2] < 3.14], top, wall])  # its back face against the wall
    rough = box + np.array([0.03, -0.04, 0.02, 0.06, 0.06, 0.06, 0.0])
    corners = box_corners_camera(np.stack([box, rough, fit_box(points, rough, margin_m=0.1)]), np.eye(3))
    low, high = corners.min(axis=1), corners.max(axis=1)  # x, y, z extents of the three boxes
    (x0, y0, z0), (x1, y1, z1) = low.T.reshape(3, 3), high.T.reshape(3, 3)  # rows: box, rough, fitted
    # The wall runs on left, right and above: there the rough box's faces, not the margin's edge.
    assert abs(x0[2] - x0[1]) < 0.01 and abs(x1[2] - x1[1]) < 0.01 and abs(y0[2] - y0[1]) < 0.01
    # The box's own front face, the wall behind it and the counter top under it end where they are.
    assert abs(z0[2] - z0[0]) < 0.02 and abs(z1[2] - 3.15) < 0.02 and abs(y1[2] + 0.9) < 0.02


def _view_from_the_front(depth_m: float) -> DepthView:
    """A camera 3 m in front of the door below (looking along +z), its depth ``depth_m`` everywhere
    (10: it sees through the space round the door; 0: it measured nothing)."""
    pose = make_pose(np.eye(3), [1.0, -1.0, 0.0])
    depth = np.full((90, 120), depth_m, np.float32)
    return DepthView(depth, Intrinsics(40.0, 40.0, 59.5, 44.5), 1, invert_pose(pose))


def test_a_face_the_points_end_at_only_because_no_frame_saw_further_stays_the_rough_boxs() -> None:
    rng = np.random.default_rng(5)
    door = np.array([1.0, -1.05, 3.0, 0.9, 0.08, 2.1, 0.0])  # standing on the floor at y = 0
    seen = surface_points(door, 3000, rng)
    points = seen[seen[:, 1] > -1.75]  # its top 35 cm out of every frame's view
    rough = door + np.array([0.02, -0.03, 0.0, 0.04, 0.02, 0.06, 0.0])
    unseen = fitted_box(points, rough, floor_y=0.0, views=[_view_from_the_front(0.0)])
    assert _top(unseen.box) == pytest.approx(_top(rough), abs=0.005)  # and its bottom on the floor:
    assert unseen.box[1] + unseen.box[5] / 2 == pytest.approx(0.0) and unseen.unseen == ("top",)
    seen_through = fitted_box(points, rough, floor_y=0.0, views=[_view_from_the_front(10.0)])
    assert _top(seen_through.box) == pytest.approx(-1.75, abs=0.03) and seen_through.unseen == ()
    assert _top(fit_box(points, rough, floor_y=0.0)) == pytest.approx(-1.75, abs=0.03)  # no views: as before


def _top(box: np.ndarray) -> float:
    """A world box's top (y is down)."""
    return box[1] - box[5] / 2


def test_space_behind_a_view_or_nearer_than_its_depth_is_not_seen_free() -> None:
    view = _view_from_the_front(10.0)  # at z = 0, looking along +z, its depth 10 m everywhere
    points = np.array([[1.0, -1.0, 3.0], [1.0, -1.0, -3.0], [1.0, -1.0, 12.0]])
    np.testing.assert_array_equal(seen_free(points, [view]), [True, False, False])  # ahead; behind; beyond it


def test_points_spanning_under_half_of_a_rough_box_keep_its_sides_across_them() -> None:
    rng = np.random.default_rng(4)
    chair = np.array([0.0, -0.45, 3.0, 0.5, 0.5, 0.9, 0.0])  # a chair: its back, seen from behind
    back = np.array([0.0, -0.45, 3.2, 0.5, 0.06, 0.9, 0.0])
    partial = fitted_box(surface_points(back, 400, rng), chair)
    assert partial.part_seen == 1
    assert sorted(np.round(partial.box[3:5], 2)) == [0.5, 0.5] and partial.box[2] == pytest.approx(3.0)
    door = np.array([0.0, -1.0, 3.0, 0.9, 0.04, 2.0, 0.0])  # thin by nature: its points are all of it
    thin = fitted_box(surface_points(door, 400, rng), door + np.array([0, 0, 0.02, 0, 0.06, 0, 0]))
    assert thin.part_seen == 0 and thin.box[4] == pytest.approx(0.04, abs=0.01)
