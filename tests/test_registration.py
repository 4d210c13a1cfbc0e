"""Depth registration (a3d.runtime.frontend.registration): geometry worked by hand, the z-buffer,
holes, and agreement with depth rendered in the colour camera itself (a3d-synth)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.registration import DepthToColor, register_depth
from a3d.runtime.structures.geometry import Intrinsics
from a3d.synth.cli import scaled_intrinsics
from a3d.synth.depth_camera import offset_depth_camera, render_depth_from
from a3d.synth.scene import SceneConfig, generate_frame

K = Intrinsics(100.0, 100.0, 39.5, 29.5)
SIZE = (60, 80)


def test_plane_moves_by_its_disparity_and_leaves_the_uncovered_strip_empty():
    # A fronto-parallel wall at 2 m; the depth camera 0.1 m to the colour camera's left
    # (p_color = p_depth + (-0.1, 0, 0)): seen from colour it shifts by f * 0.1 / 2 = 5 px left.
    depth = np.full(SIZE, 2.0)
    reg = register_depth(depth, DepthToColor(K, np.eye(3), [-0.1, 0.0, 0.0]), K, SIZE)
    assert reg.dtype == np.float32 and reg.shape == SIZE
    assert np.all(reg[:, :75] == pytest.approx(2.0, abs=1e-6))
    assert np.all(reg[:, 75:] == 0)  # beyond the depth camera's view: a hole


def test_depth_camera_closer_to_the_wall_reads_farther_in_colour():
    depth = np.full(SIZE, 2.0)
    reg = register_depth(depth, DepthToColor(K, np.eye(3), [0.0, 0.0, 0.25]), K, SIZE)
    inside = reg > 0
    assert inside[20:40, 30:50].all()
    assert np.allclose(reg[inside], 2.25, atol=1e-6)


def test_nearest_surface_wins_and_the_disoccluded_strip_stays_a_hole():
    depth = np.full(SIZE, 3.0)
    depth[20:40, 30:50] = 1.0  # a box 2 m in front of the wall
    reg = register_depth(depth, DepthToColor(K, np.eye(3), [0.1, 0.0, 0.0]), K, SIZE)
    # Box: shifted 10 px right (f * 0.1 / 1); wall: 3.33 px right; both land on cols 40..59.
    assert np.allclose(reg[22:38, 41:59], 1.0, atol=1e-6)
    # Just left of the box the colour camera sees wall the depth camera could not: a hole, not
    # a ramp from 1 m to 3 m.
    assert np.all(reg[22:38, 35:39] == 0)
    assert np.allclose(reg[22:38, 10:30], 3.0, atol=1e-6)


def test_missing_depth_stays_missing():
    depth = np.full(SIZE, 2.0)
    depth[10:20, 10:20] = 0
    reg = register_depth(depth, DepthToColor(K, np.eye(3), [0.0, 0.0, 0.0]), K, SIZE)
    assert np.all(reg[11:19, 11:19] == 0) and np.allclose(reg[30:, 30:], 2.0)


def test_calibration_is_checked():
    with pytest.raises(InputError, match="extrinsics rotation"):
        DepthToColor(K, np.eye(3) * 2, [0, 0, 0])
    with pytest.raises(InputError, match="extrinsics translation"):
        DepthToColor(K, np.eye(3), [0, 0])


@pytest.mark.slow
def test_registered_synthetic_depth_agrees_with_the_colour_cameras_own_to_1mm():
    size = (240, 320)
    config = replace(SceneConfig(), image_size=size, intrinsics=scaled_intrinsics(size), noise=False)
    calibration, depth_size = offset_depth_camera(size)
    within, both = 0, 0
    for seed in (0, 2):
        truth = generate_frame(seed, config).depth_exact
        seen = render_depth_from(seed, config, calibration, depth_size)
        assert not np.allclose(seen[: size[0], : size[1]], truth)  # really another view
        reg = register_depth(seen, calibration, config.intrinsics, size)
        have = (reg > 0) & (truth > 0)
        assert have.mean() > 0.75
        within += int(np.count_nonzero(np.abs(reg - truth)[have] <= 0.001))
        both += int(np.count_nonzero(have))
    assert within / both >= 0.95


def test_the_offset_camera_renders_the_same_scene_with_clutter():
    """render_depth_from rebuilds generate_frame's scene from the seed, clutter included: from
    the colour camera's own pose it gives the colour camera's depth exactly."""
    size = (48, 64)
    config = replace(
        SceneConfig(), image_size=size, intrinsics=scaled_intrinsics(size), noise=False, clutter=6
    )
    same = DepthToColor(config.intrinsics, np.eye(3), [0.0, 0.0, 0.0])
    for seed in (3, 4):
        np.testing.assert_array_equal(
            render_depth_from(seed, config, same, size), generate_frame(seed, config).depth_exact
        )
