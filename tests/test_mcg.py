"""MCG ``candidates.mat`` -> precomputed proposals, on small candidate files written here."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from a3d.runtime.errors import InputError
from a3d.runtime.sources import proposals_file
from a3d.train.data import mcg

H, W = 20, 30


def superpixels() -> np.ndarray:
    """Labels 1..S: a 4 x 5 grid of blocks, with an L-shaped region cut out as label 21."""
    sp = (np.arange(H)[:, None] // 5) * 5 + np.arange(W)[None] // 6 + 1
    sp[12:18, 2:4] = 21
    sp[16:18, 4:9] = 21
    return sp.astype(np.uint32)


MEMBERS = [
    [21],
    [1, 2, 7],
    [8],
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21],
    [20],
]
SCORES = [0.9, 0.7, 0.5, 0.3, 0.1]


def masks() -> np.ndarray:
    return np.stack([np.isin(superpixels(), m) for m in MEMBERS])


def mcg_bboxes(masks: np.ndarray) -> np.ndarray:
    """MCG's ``mask2box``: [ymin xmin ymax xmax], 1-based inclusive indices of the mask's pixels."""
    out = []
    for m in masks:
        rows, cols = np.nonzero(m)
        out.append([rows.min() + 1, cols.min() + 1, rows.max() + 1, cols.max() + 1])
    return np.array(out, dtype=np.float64)


def pixel_boxes(masks: np.ndarray) -> np.ndarray:
    """README boxes: the exact extent of the mask's pixels."""
    out = []
    for m in masks:
        rows, cols = np.nonzero(m)
        out.append([cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5])
    return np.array(out)


def write_candidates(
    path: Path, *, as_struct: bool = True, bboxes: np.ndarray | None = None, members=MEMBERS
) -> Path:
    labels = np.empty((len(members), 1), dtype=object)
    for i, m in enumerate(members):
        labels[i, 0] = np.array(m, dtype=np.uint32 if i % 2 else np.float64)[None]
    fields = {
        "superpixels": superpixels(),
        "labels": labels,
        "bboxes": mcg_bboxes(masks()) if bboxes is None else bboxes,
        "scores": np.array(SCORES)[:, None],
    }
    scipy.io.savemat(path, {"candidates": fields} if as_struct else fields)
    return path


def test_candidates_become_superpixel_proposals(tmp_path: Path) -> None:
    proposals = mcg.read_mcg_candidates(write_candidates(tmp_path / "candidates.mat"))
    assert len(proposals) == len(MEMBERS) and proposals.image_size == (H, W)
    assert np.array_equal(proposals.boxes, pixel_boxes(masks()).astype(np.float32))
    assert np.array_equal(proposals.scores, np.float32(SCORES))
    for i, expected in enumerate(masks()):
        assert np.array_equal(proposals.mask(i), expected), i
    # The L-shaped segment: rows 12..17, columns 2..8 -> pixel edges [1.5, 11.5, 8.5, 17.5].
    assert proposals.boxes[0].tolist() == [1.5, 11.5, 8.5, 17.5]
    top_level = mcg.read_mcg_candidates(write_candidates(tmp_path / "flat.mat", as_struct=False))
    assert np.array_equal(top_level.indices, proposals.indices) and np.array_equal(
        top_level.boxes, proposals.boxes
    )


def test_written_proposals_read_back_identically(tmp_path: Path) -> None:
    proposals = mcg.read_mcg_candidates(write_candidates(tmp_path / "candidates.mat"))
    path = tmp_path / "0001.proposals.npz"
    proposals_file.write_precomputed_proposals(path, proposals)
    read = proposals_file.read_precomputed_proposals(path, (H, W))
    for field in ("boxes", "scores", "superpixels", "indptr", "indices"):
        assert np.array_equal(getattr(read, field), getattr(proposals, field)), field
    assert read.superpixels.dtype == np.int32 and read.indptr.dtype == np.int64


def test_small_boxes_are_dropped_and_the_first_kept(tmp_path: Path) -> None:
    path = write_candidates(tmp_path / "candidates.mat")
    areas = np.prod(pixel_boxes(masks())[:, 2:] - pixel_boxes(masks())[:, :2], axis=1)  # 42, 120, 30, 600, 30
    proposals = mcg.read_mcg_candidates(path, min_box_area=40, max_proposals=2)
    kept = np.flatnonzero(areas >= 40)[:2]
    assert kept.tolist() == [0, 1]
    assert np.array_equal(proposals.boxes, pixel_boxes(masks())[kept].astype(np.float32))
    assert np.array_equal(proposals.scores, np.float32(SCORES)[kept])
    for j, i in enumerate(kept):
        assert np.array_equal(proposals.mask(j), masks()[i])
    assert len(mcg.read_mcg_candidates(path, min_box_area=1e6)) == 0


def test_boxes_in_another_order_or_base_are_rejected(tmp_path: Path) -> None:
    boxes = mcg_bboxes(masks())
    path = write_candidates(tmp_path / "xy.mat", bboxes=boxes[:, [1, 0, 3, 2]])  # [xmin ymin xmax ymax]
    with pytest.raises(InputError, match=r"xy\.mat: bboxes of candidate 1 .* does not match its segment"):
        mcg.read_mcg_candidates(path)
    path = write_candidates(tmp_path / "zero.mat", bboxes=boxes - 1)  # 0-based
    with pytest.raises(InputError, match="does not match its segment"):
        mcg.read_mcg_candidates(path)


def test_bad_candidate_files(tmp_path: Path) -> None:
    path = write_candidates(tmp_path / "labels.mat", members=[*MEMBERS[:-1], [22]])
    with pytest.raises(InputError, match=r"labels\.mat: labels\{5\} must be superpixel labels in \[1, 21\]"):
        mcg.read_mcg_candidates(path)
    path = write_candidates(tmp_path / "short.mat", bboxes=mcg_bboxes(masks())[:3])
    with pytest.raises(InputError, match=r"short\.mat: bboxes is \(3, 4\); expected \(5, 4\)"):
        mcg.read_mcg_candidates(path)
    scipy.io.savemat(tmp_path / "none.mat", {"other": np.zeros(3)})
    with pytest.raises(InputError, match=r"none\.mat: no 'superpixels'"):
        mcg.read_mcg_candidates(tmp_path / "none.mat")
