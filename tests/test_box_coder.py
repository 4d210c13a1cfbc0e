"""Box coder: the docs/conventions.md 3D targets by hand, Fast R-CNN 2D deltas, round trips, broadcasting."""

from __future__ import annotations

import math

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.postprocess.box_coder import MAX_LOG_SCALE, decode_2d, decode_3d, encode_2d, encode_3d


def test_encode_3d_is_the_spec_formula():
    P = np.array([[1.0, 0.5, 3.0, 2.0, 0.8, 1.6, 0.0]])
    G = np.array([[1.4, 0.1, 3.2, 1.0, 1.6, 0.4, -0.7]])
    expected = [0.4 / 2.0, -0.4 / 1.6, 0.2 / 0.8, math.log(0.5), math.log(2.0), math.log(0.25), -0.7]
    np.testing.assert_allclose(encode_3d(P, G), [expected], atol=1e-15)  # x/l, y/h, z/w


def test_decode_3d_is_the_spec_inverse_with_theta_as_regressed():
    P = np.array([[1.0, 0.5, 3.0, 2.0, 0.8, 1.6, 0.3]])
    d = np.array([[0.1, -0.2, 0.5, math.log(1.5), 0.0, math.log(0.5), 1.2]])
    np.testing.assert_allclose(decode_3d(P, d), [[1.2, 0.18, 3.4, 3.0, 0.8, 0.8, 1.2]], atol=1e-15)
    np.testing.assert_allclose(decode_3d(P, np.zeros((1, 7))), [[1.0, 0.5, 3.0, 2.0, 0.8, 1.6, 0.0]])


def test_3d_round_trip():
    rng = np.random.default_rng(0)
    n = 500
    P = np.column_stack([rng.normal(0, 1, (n, 3)), rng.uniform(0.1, 3, (n, 3)), np.zeros(n)])
    G = np.column_stack([rng.normal(0, 1, (n, 3)), rng.uniform(0.1, 3, (n, 3)), rng.uniform(-1.5, 1.5, n)])
    np.testing.assert_allclose(decode_3d(P, encode_3d(P, G)), G, rtol=1e-12, atol=1e-12)
    d = rng.normal(0, 1, (n, 7))
    np.testing.assert_allclose(encode_3d(P, decode_3d(P, d)), d, rtol=1e-12, atol=1e-12)


def test_decode_3d_broadcasts_over_classes():
    rng = np.random.default_rng(1)
    P = np.column_stack([rng.normal(0, 1, (6, 3)), rng.uniform(0.1, 3, (6, 3)), np.zeros(6)])
    d = rng.normal(0, 0.3, (6, 20, 7))
    out = decode_3d(P[:, None, :], d)
    assert out.shape == (6, 20, 7)
    np.testing.assert_allclose(out[4, 13], decode_3d(P[4:5], d[4, 13][None])[0])


def test_2d_known_values_and_round_trip():
    rois = np.array([[10.0, 20.0, 30.0, 60.0]])  # centre (20, 40), size (20, 40): no "+1"
    gt = np.array([[15.0, 10.0, 55.0, 50.0]])  # centre (35, 30), size (40, 40)
    np.testing.assert_allclose(encode_2d(rois, gt), [[15 / 20, -10 / 40, math.log(2.0), 0.0]], atol=1e-15)
    np.testing.assert_allclose(decode_2d(rois, encode_2d(rois, gt)), gt, atol=1e-12)
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 500, (300, 2))
    r = np.hstack([xy, xy + rng.uniform(1, 200, (300, 2))])
    d = rng.normal(0, 0.5, (300, 4))
    np.testing.assert_allclose(encode_2d(r, decode_2d(r, d)), d, atol=1e-10)
    assert decode_2d(r[:, None, :], d[:, None, :].repeat(3, axis=1)).shape == (300, 3, 4)


def test_decoding_clamps_wild_log_scales_instead_of_overflowing():
    P = np.array([[0, 0, 3, 1.0, 1.0, 1.0, 0]])
    out = decode_3d(P, np.array([[0, 0, 0, 1000.0, 800.0, -5.0, 0]]))
    big = math.exp(MAX_LOG_SCALE)  # 62.5
    np.testing.assert_allclose(out[0, 3:6], [big, big, math.exp(-5.0)])
    box = decode_2d(np.array([[0, 0, 10.0, 10.0]]), np.array([[0, 0, 1e4, 0.0]]))
    np.testing.assert_allclose(box, [[5 - 5 * 1000 / 16, 0, 5 + 5 * 1000 / 16, 10]])


def test_bad_inputs_raise_clear_errors():
    P = np.array([[0, 0, 3, 1.0, 1.0, 1.0, 0]])
    with pytest.raises(InputError, match="proposals: sizes must be positive"):
        encode_3d(P * [1, 1, 1, 0, 1, 1, 1], P)
    with pytest.raises(InputError, match="gt boxes: sizes must be positive"):
        encode_3d(P, P * [1, 1, 1, 1, 1, -1, 1])
    with pytest.raises(InputError, match="deltas3d: NaN"):
        decode_3d(P, np.full((1, 7), np.nan))
    with pytest.raises(InputError, match=r"\(\.\.\., 7\)"):
        decode_3d(P, np.zeros((1, 6)))
    with pytest.raises(InputError, match="rois: sizes must be positive"):
        encode_2d(np.array([[5.0, 5.0, 5.0, 9.0]]), np.array([[0, 0, 1.0, 1.0]]))
