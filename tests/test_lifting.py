"""Lifting proposals to initial 3D boxes: parity with a brute-force per-mask np.median reference."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from a3d.runtime.frontend.lifting import LiftConfig, initial_boxes, lift, masks_to_superpixels
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS as K

BIN = LiftConfig().bin_width


@dataclass
class SuperpixelSet:
    """A stand-in with the attributes lift reads from a3d.runtime.frontend.proposals.Proposals."""

    superpixels: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray


def _scene(seed: int, h: int = 96, w: int = 128, hole_fraction: float = 0.3):
    """Random blob superpixels, random depth in 0.5..8 m with holes, and a hole-filled copy."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 60, size=(h // 8, w // 8)).astype(np.float32)
    labels = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int32)
    labels = np.unique(labels, return_inverse=True)[1].reshape(h, w).astype(np.int32)
    raw = rng.uniform(0.5, 8.0, size=(h, w)).astype(np.float32)
    raw[rng.random((h, w)) < hole_fraction] = 0
    filled = np.where(raw > 0, raw, rng.uniform(0.5, 8.0, size=(h, w))).astype(np.float32)
    return labels, raw, filled


def _random_csr(rng: np.random.Generator, n: int, n_sp: int) -> tuple[np.ndarray, np.ndarray]:
    members = [np.sort(rng.choice(n_sp, size=rng.integers(1, 8), replace=False)) for _ in range(n)]
    indptr = np.concatenate([[0], np.cumsum([len(m) for m in members])])
    return indptr, np.concatenate(members)


def _reference(mask: np.ndarray, raw: np.ndarray, filled: np.ndarray) -> tuple[np.ndarray, bool]:
    """docs/conventions.md "Proposals and initial 3D boxes", one mask at a time."""
    d = raw[mask]
    from_filled = not (d > 0).any()
    z = float(np.median(filled[mask] if from_filled else d[d > 0]))
    v, u = np.nonzero(mask)
    return np.array([(u.mean() - K.cx) * z / K.fx, (v.mean() - K.cy) * z / K.fy, z]), from_filled


def _check_against_reference(out, masks, raw, filled) -> None:
    for i, mask in enumerate(masks):
        ref, ref_filled = _reference(mask, raw, filled)
        assert out.valid[i] and out.from_filled[i] == ref_filled
        assert abs(out.centers[i, 2] - ref[2]) < BIN  # the stated bound: one bin width
        # (x, y) is the centroid ray at that z: the ray itself is exact.
        np.testing.assert_allclose(
            out.centers[i, :2] / out.centers[i, 2], ref[:2] / ref[2], rtol=0, atol=1e-9
        )


def test_superpixel_form_matches_per_mask_median() -> None:
    labels, raw, filled = _scene(0)
    indptr, indices = _random_csr(np.random.default_rng(1), 300, int(labels.max()) + 1)
    out = lift(SuperpixelSet(labels, indptr, indices), raw, filled, K)
    masks = [np.isin(labels, indices[a:b]) for a, b in itertools.pairwise(indptr)]
    _check_against_reference(out, masks, raw, filled)
    assert np.isfinite(out.centers).all()


def test_mask_stack_matches_per_mask_median() -> None:
    _, raw, filled = _scene(2)
    rng = np.random.default_rng(3)
    h, w = raw.shape
    masks = np.zeros((40, h, w), bool)
    for m in masks:  # overlapping random rectangles
        y0, x0 = rng.integers(0, h - 5), rng.integers(0, w - 5)
        m[y0 : y0 + rng.integers(2, 40), x0 : x0 + rng.integers(2, 40)] = True
    _check_against_reference(lift(masks, raw, filled, K), masks, raw, filled)


def test_masks_to_superpixels_is_exact() -> None:
    rng = np.random.default_rng(4)
    masks = rng.random((11, 20, 30)) < 0.4
    labels, indptr, indices = masks_to_superpixels(masks)
    for i, mask in enumerate(masks):
        np.testing.assert_array_equal(np.isin(labels, indices[indptr[i] : indptr[i + 1]]), mask)


def test_proposal_inside_a_depth_hole_uses_filled_depth() -> None:
    raw = np.full((40, 50), 2.0, np.float32)
    raw[10:20, 10:30] = 0  # a hole
    filled = raw.copy()
    filled[10:20, 10:30] = np.linspace(3.0, 4.0, 20, dtype=np.float32)[None, :]
    masks = np.zeros((2, 40, 50), bool)
    masks[0, 12:18, 12:28] = True  # entirely inside the hole
    masks[1, 5:25, 5:35] = True  # overlaps it: raw depth wins
    out = lift(masks, raw, filled, K)
    assert out.valid.all()
    assert out.from_filled.tolist() == [True, False]
    assert abs(out.centers[0, 2] - np.median(filled[masks[0]])) < BIN
    assert abs(out.centers[1, 2] - 2.0) < BIN


def test_one_pixel_segment() -> None:
    raw = np.zeros((30, 40), np.float32)
    raw[7, 9] = 3.217
    masks = np.zeros((1, 30, 40), bool)
    masks[0, 7, 9] = True
    out = lift(masks, raw, raw, K)
    expected = np.array([(9 - K.cx) * 3.217 / K.fx, (7 - K.cy) * 3.217 / K.fy, 3.217])
    assert out.valid[0] and not out.from_filled[0]
    np.testing.assert_allclose(out.centers[0], expected, atol=BIN)


def test_even_count_median_averages_the_two_middle_values() -> None:
    raw = np.zeros((10, 10), np.float32)
    raw[2, 2], raw[2, 3] = 1.0, 5.0  # np.median of a two-pixel segment is 3.0
    masks = np.zeros((1, 10, 10), bool)
    masks[0, 2, 2:4] = True
    assert abs(lift(masks, raw, raw, K).centers[0, 2] - 3.0) < BIN


def test_all_zero_depth_and_empty_proposals_are_invalid_not_nan() -> None:
    labels = np.zeros((20, 30), np.int32)
    labels[:, 15:] = 1
    zeros = np.zeros((20, 30), np.float32)
    proposals = SuperpixelSet(labels, np.array([0, 1, 1, 3]), np.array([0, 0, 1]))  # 2nd is empty
    out = lift(proposals, zeros, zeros, K)
    assert not out.valid.any() and not out.from_filled.any()
    np.testing.assert_array_equal(out.centers, 0.0)
    depth = np.full((20, 30), 2.0, np.float32)
    out = lift(proposals, depth, depth, K)
    assert out.valid.tolist() == [True, False, True]
    np.testing.assert_array_equal(out.centers[1], 0.0)


def test_bad_input_is_rejected() -> None:
    labels = np.zeros((20, 30), np.int32)
    depth = np.ones((20, 30), np.float32)
    with pytest.raises(ValueError, match="one size"):
        lift(SuperpixelSet(labels, np.array([0, 1]), np.array([0])), depth[:10], depth, K)
    with pytest.raises(ValueError, match="member ids"):
        lift(SuperpixelSet(labels, np.array([0, 1]), np.array([5])), depth, depth, K)


def test_initial_boxes_broadcast_class_sizes() -> None:
    centers = np.array([[0.1, 0.2, 3.0], [-1.0, 0.5, 2.0]])
    sizes = np.arange(19 * 3, dtype=np.float64).reshape(19, 3) + 1
    boxes = initial_boxes(centers, sizes)
    assert boxes.shape == (2, 19, 7)
    np.testing.assert_array_equal(boxes[1, 4], [-1.0, 0.5, 2.0, *sizes[4], 0.0])
    np.testing.assert_array_equal(boxes[:, :, 6], 0.0)
