"""Gravity (R_tilt) estimation and surface normals on rendered planar rooms with a known R_tilt."""

from __future__ import annotations

import math

import numpy as np
import pytest

from a3d.runtime.frontend.gravity import (
    STATUS_OK,
    STATUS_TOO_FEW_NORMALS,
    STATUS_WALLS_ONLY,
    estimate_gravity,
    estimate_rtilt,
    rtilt_from_gravity,
)
from a3d.runtime.frontend.normals import NormalConfig, surface_normals
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS as K
from a3d.runtime.structures.geometry import is_rotation, pitch_roll_from_rtilt, rtilt_from_pitch_roll

ROOM = ((1, 1.3), (1, -1.4), (0, -2.0), (0, 2.5), (2, 4.0))  # floor, ceiling, side walls, back wall
CORNER = ((0, -0.8), (2, 2.5))  # two walls, no floor


def render(
    R_tilt: np.ndarray, planes, shape=(427, 561), noise: float = 0.0, holes: float = 0.0, seed: int = 0
):
    """Depth of axis-aligned tilt-frame planes (axis, offset): p_tilt[axis] = offset, seen by a
    camera with p_tilt = R_tilt p_cam. Optional relative noise and missing pixels."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1) @ R_tilt.T
    depth = np.full(shape, np.inf)
    for axis, offset in planes:
        with np.errstate(divide="ignore"):
            t = offset / rays[..., axis]
        depth = np.minimum(depth, np.where(t > 0, t, np.inf))  # camera-frame z of the ray is 1: z = t
    depth[~np.isfinite(depth)] = 0
    rng = np.random.default_rng(seed)
    depth *= 1 + noise * rng.standard_normal(shape)
    depth[rng.random(shape) < holes] = 0
    return depth.astype(np.float32)


def angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle between the gravity directions of two R_tilt."""
    return math.degrees(math.acos(min(1.0, float(R_a[1] @ R_b[1]))))


@pytest.mark.parametrize("pitch, roll", [(-5, 5), (-15, -3), (-25, 2), (-35, -5), (-35, 5)])
def test_recovers_known_rtilt_within_one_degree(pitch: float, roll: float) -> None:
    truth = rtilt_from_pitch_roll(math.radians(pitch), math.radians(roll))
    depth = render(truth, ROOM, noise=0.005, holes=0.1, seed=abs(pitch) + 10 * abs(roll))
    est = estimate_gravity(depth, K)
    assert est.status == STATUS_OK
    assert angle_deg(est.R_tilt, truth) < 1.0
    np.testing.assert_allclose(est.R_tilt @ est.gravity, [0, 1, 0], atol=1e-9)
    got = np.degrees(pitch_roll_from_rtilt(est.R_tilt))  # raises unless R_x R_z form
    np.testing.assert_allclose(got, [pitch, roll], atol=1.0)


def test_rtilt_from_gravity_inverts_pitch_roll() -> None:
    for pitch, roll in [(-0.6, 0.1), (0.2, -0.05), (0.0, 0.0)]:
        R = rtilt_from_pitch_roll(pitch, roll)
        np.testing.assert_allclose(rtilt_from_gravity(R.T @ [0, 1, 0]), R, atol=1e-12)


def test_all_zero_depth_falls_back_to_identity() -> None:
    est = estimate_gravity(np.zeros((427, 561), np.float32), K)
    assert est.status == STATUS_TOO_FEW_NORMALS
    np.testing.assert_array_equal(est.R_tilt, np.eye(3))
    np.testing.assert_array_equal(estimate_rtilt(np.zeros((60, 80), np.float32), K), np.eye(3))


def test_no_visible_floor_uses_the_walls() -> None:
    truth = rtilt_from_pitch_roll(math.radians(-20), math.radians(4))
    est = estimate_gravity(render(truth, CORNER, noise=0.005, seed=1), K)
    assert est.status == STATUS_WALLS_ONLY and est.n_floor == 0
    assert angle_deg(est.R_tilt, truth) < 1.0  # two wall orientations pin gravity down


def test_single_wall_no_floor_projects_camera_y_onto_the_wall() -> None:
    truth = rtilt_from_pitch_roll(math.radians(-20), math.radians(4))
    est = estimate_gravity(render(truth, ((2, 2.0),)), K)
    assert est.status == STATUS_WALLS_ONLY
    wall_normal = truth.T @ [0.0, 0.0, 1.0]  # camera frame
    expected = np.array([0.0, 1.0, 0.0]) - wall_normal[1] * wall_normal
    expected /= np.linalg.norm(expected)
    assert math.degrees(math.acos(min(1.0, est.gravity @ expected))) < 0.5
    assert is_rotation(est.R_tilt) and np.isfinite(est.R_tilt).all()


def test_unstructured_depth_gives_a_finite_rotation() -> None:
    depth = np.random.default_rng(5).uniform(0.5, 5.0, size=(120, 160)).astype(np.float32)
    est = estimate_gravity(depth, K)
    assert is_rotation(est.R_tilt) and np.isfinite(est.gravity).all()


def test_surface_normals_of_a_plane_are_exact_and_face_the_camera() -> None:
    R = rtilt_from_pitch_roll(math.radians(-30), math.radians(3))
    depth = render(R, ((1, 1.3),))  # floor only; above the horizon there is no depth
    depth[200:220, 300:330] = 0  # a hole
    normals = surface_normals(depth, K)
    assert normals.shape == (*depth.shape, 3) and normals.dtype == np.float32
    valid = np.abs(normals).sum(axis=2) > 0
    assert valid.mean() > 0.3
    floor_up = R.T @ [0.0, -1.0, 0.0]  # the floor's normal, toward the camera (up), camera frame
    np.testing.assert_allclose(normals[valid], np.broadcast_to(floor_up, (int(valid.sum()), 3)), atol=1e-3)
    assert not valid[depth == 0].any()


def test_depth_discontinuity_gets_no_normal() -> None:
    depth = np.full((120, 160), 3.0, np.float32)
    depth[:, 80:] = 1.5  # a step edge between two fronto-parallel planes
    normals = surface_normals(depth, K, NormalConfig(step=2, window=5))
    valid = np.abs(normals).sum(axis=2) > 0
    assert not valid[:, 74:86].any()  # no normal mixes the two planes
    np.testing.assert_allclose(normals[valid][:, 2], -1.0, atol=1e-5)
