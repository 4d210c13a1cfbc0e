"""Network input preprocessing: the exact constants of docs/conventions.md "Network"."""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.network.preprocess import (
    COLOR_MEAN_BGR,
    DEPTH_MEAN,
    DEPTH_TRUNCATION_M,
    color_input,
    depth_input,
)


def test_constants_match_the_release() -> None:
    np.testing.assert_array_equal(COLOR_MEAN_BGR, np.float32([102.98, 115.95, 122.77]))
    assert DEPTH_MEAN == 72.81
    assert DEPTH_TRUNCATION_M == 10.0


def test_color_input_subtracts_bgr_mean_in_chw() -> None:
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[0, 1] = (10, 200, 255)  # B, G, R of pixel (row 0, col 1)
    out = color_input(bgr)
    assert out.shape == (3, 2, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out[:, 0, 1], [10 - 102.98, 200 - 115.95, 255 - 122.77], rtol=0, atol=1e-4)
    np.testing.assert_allclose(out[:, 1, 2], [-102.98, -115.95, -122.77], rtol=0, atol=1e-4)


def test_depth_input_truncates_scales_and_replicates() -> None:
    depth = np.array([[0.0, 5.0, 10.0, 12.0]], np.float32)
    out = depth_input(depth)
    assert out.shape == (3, 1, 4) and out.dtype == np.float32
    np.testing.assert_allclose(out[0, 0], [-72.81, 127.5 - 72.81, 255 - 72.81, 255 - 72.81], atol=1e-4)
    np.testing.assert_array_equal(out[0], out[1])
    np.testing.assert_array_equal(out[0], out[2])


def test_depth_input_truncation_parameter_paper_value() -> None:
    out = depth_input(np.array([[4.0, 8.0, 9.0]], np.float32), truncation=8.0)
    np.testing.assert_allclose(out[0, 0], [127.5 - 72.81, 255 - 72.81, 255 - 72.81], atol=1e-4)


def test_bad_shapes_are_rejected() -> None:
    with pytest.raises(ValueError, match="uint8"):
        color_input(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="depth"):
        depth_input(np.zeros((3, 4, 4), np.float32))
    with pytest.raises(ValueError, match="truncation"):
        depth_input(np.zeros((4, 4), np.float32), truncation=0.0)
