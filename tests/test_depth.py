"""Depth hole filling: no zeros left, valid pixels untouched, shadows filled from the far side."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.depth import fill_depth, fill_depth_info


def _ramp(h: int = 427, w: int = 561) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w]
    return (2.0 + 0.003 * u + 0.002 * v).astype(np.float32)


def test_fill_leaves_no_zeros_and_keeps_valid_pixels() -> None:
    rng = np.random.default_rng(0)
    truth = _ramp()
    depth = truth.copy()
    depth[rng.random(depth.shape) < 0.2] = 0  # scattered holes
    depth[200:300, 50:200] = 0  # a large hole
    depth[:, -7:] = 0  # a hole along the border
    filled = fill_depth(depth)
    assert filled.dtype == np.float32 and filled.shape == depth.shape
    assert (filled > 0).all() and np.isfinite(filled).all()
    valid = depth > 0
    np.testing.assert_array_equal(filled[valid], depth[valid])
    # On a smooth surface the fill is close to the surface (inpainting is not exact on a ramp).
    assert np.abs(filled - truth)[~valid].max() < 0.2


def test_occlusion_shadow_is_filled_from_the_far_side() -> None:
    depth = np.full((120, 160), 3.0, np.float32)
    depth[30:90, 40:70] = 1.0  # a near object
    depth[30:90, 70:82] = 0  # its shadow on the wall behind, to its right
    filled = fill_depth(depth)
    np.testing.assert_allclose(filled[30:90, 70:82], 3.0, atol=1e-5)


def test_all_zero_frame_returns_zeros_and_flag() -> None:
    info = fill_depth_info(np.zeros((50, 60), np.float32))
    assert info.empty and info.hole_fraction == 1.0
    assert info.depth.shape == (50, 60) and not info.depth.any()


def test_single_valid_pixel_fills_everything_with_its_value() -> None:
    depth = np.zeros((37, 41), np.float32)
    depth[5, 7] = 2.5
    info = fill_depth_info(depth)
    assert not info.empty
    np.testing.assert_allclose(info.depth, 2.5, rtol=1e-5)


def test_no_holes_is_identity() -> None:
    depth = _ramp(30, 40)
    info = fill_depth_info(depth)
    assert info.hole_fraction == 0.0
    np.testing.assert_array_equal(info.depth, depth)


@pytest.mark.parametrize("value", [np.nan, np.inf, -1.0])
def test_bad_values_are_rejected(value: float) -> None:
    depth = np.ones((10, 10), np.float32)
    depth[3, 3] = value
    with pytest.raises(InputError, match="depth"):
        fill_depth(depth)
