"""MCG candidate files (``candidates.mat``) -> precomputed proposals (README "Precomputed proposals").

Layout, as MCG's ``im2mcg`` writes it (github jponttuset/mcg) and the authors' ``get_proposals.m``
reads it: a struct ``candidates`` (the authors' ``Segs/NYU%04d/candidates.mat``), or the same
fields as top-level variables (as saved by Gupta et al.'s RGB-D MCG), with

* ``superpixels`` (H, W): the superpixel label map, labels 1..S;
* ``labels``: cell (N, 1), per candidate the superpixel labels whose union it is;
* ``bboxes`` (N, 4): ``[ymin xmin ymax xmax]``, 1-based inclusive pixel indices (MCG's
  ``mask2box``; the authors reorder it with ``(:, [2 1 4 3]) - 1``);
* ``scores`` (N, 1), optional: candidates come sorted by decreasing score.

Conversion: superpixel ids are MCG's labels unchanged (id 0 is then unused), the member lists
become CSR ``indptr`` / ``indices``, and boxes become README pixel coordinates
``[xmin - 1.5, ymin - 1.5, xmax - 0.5, ymax - 0.5]``. Each converted box must match the exact
extent of its segment (to within half a pixel): this catches a file in another box order or
base. The authors keep candidates whose box area (in pixels, inclusive) is at least 200 and
then the first 2000: ``min_box_area`` and ``max_proposals``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.sources.proposals_file import PrecomputedProposals
from a3d.runtime.structures.geometry import boxes_from_pixel_bounds
from a3d.train.data.nyuv2 import load_mat, matlab_boxes_to_pixels

AUTHORS_MIN_BOX_AREA = 200.0
AUTHORS_MAX_PROPOSALS = 2000
_BOX_TOLERANCE_PX = 0.5


def read_mcg_candidates(
    path: str | Path, *, min_box_area: float = 0.0, max_proposals: int | None = None
) -> PrecomputedProposals:
    """Read ``candidates.mat`` as superpixel-form proposals (first ``max_proposals`` of those kept)."""
    path = Path(path)
    variables = load_mat(path)
    fields = variables["candidates"] if isinstance(variables.get("candidates"), dict) else variables
    for name in ("superpixels", "labels", "bboxes"):
        if name not in fields:
            raise InputError(f"{path}: no {name!r} (expected a struct 'candidates' or top-level variables)")
    superpixels = _label_map(fields["superpixels"], path)
    members = _members(fields["labels"], path, int(superpixels.max()))
    n = len(members)
    bboxes = np.asarray(fields["bboxes"], dtype=np.float64)
    if bboxes.shape != (n, 4) or not np.isfinite(bboxes).all():
        raise InputError(f"{path}: bboxes is {bboxes.shape}; expected ({n}, 4) finite [ymin xmin ymax xmax]")
    scores = fields.get("scores")
    if scores is not None:
        scores = np.asarray(scores, dtype=np.float32).reshape(-1)
        if scores.shape != (n,):
            raise InputError(f"{path}: scores has {scores.size} entries for {n} candidates")
    boxes = matlab_boxes_to_pixels(bboxes[:, [1, 0, 3, 2]])
    extents = segment_extents(superpixels, *_csr(members))
    off = np.flatnonzero(np.abs(boxes - extents).max(axis=1, initial=0.0) > _BOX_TOLERANCE_PX)
    if off.size:
        i = int(off[0])
        raise InputError(
            f"{path}: bboxes of candidate {i + 1} {bboxes[i].tolist()} does not match its segment "
            f"(expected [ymin xmin ymax xmax], 1-based: {extents[i].tolist()} in pixel edges)"
        )
    keep = np.flatnonzero((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]) >= min_box_area)
    keep = keep[:max_proposals]
    indptr, indices = _csr([members[i] for i in keep])
    return PrecomputedProposals(
        boxes=boxes[keep].astype(np.float32),
        image_size=superpixels.shape,
        scores=None if scores is None else scores[keep],
        superpixels=superpixels,
        indptr=indptr,
        indices=indices,
    )


def segment_extents(superpixels: np.ndarray, indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """README boxes (N, 4) of the segments given as unions of superpixels (each non-empty)."""
    h, w = superpixels.shape
    count = int(superpixels.max()) + 1
    rows, cols = np.indices((h, w))
    lo_u = np.full(count, w, np.int64)
    lo_v = np.full(count, h, np.int64)
    hi_u = np.full(count, -1, np.int64)
    hi_v = np.full(count, -1, np.int64)
    flat = superpixels.ravel()
    np.minimum.at(lo_u, flat, cols.ravel())
    np.minimum.at(lo_v, flat, rows.ravel())
    np.maximum.at(hi_u, flat, cols.ravel())
    np.maximum.at(hi_v, flat, rows.ravel())
    if len(indptr) == 1:
        return np.zeros((0, 4))
    starts = indptr[:-1]
    per = [np.minimum.reduceat(lo_u[indices], starts), np.minimum.reduceat(lo_v[indices], starts)]
    per += [np.maximum.reduceat(hi_u[indices], starts), np.maximum.reduceat(hi_v[indices], starts)]
    return boxes_from_pixel_bounds(np.stack(per, axis=1))


def _label_map(value: Any, path: Path) -> np.ndarray:
    if (
        not isinstance(value, np.ndarray)
        or value.ndim != 2
        or value.dtype.kind not in "fiu"
        or value.size == 0
    ):
        raise InputError(f"{path}: superpixels must be a non-empty (H, W) label map")
    if (
        value.min() < 0
        or value.max() >= 2**31
        or (value.dtype.kind == "f" and (value != np.round(value)).any())
    ):
        raise InputError(f"{path}: superpixels must hold integer labels >= 0")
    return value.astype(np.int32)


def _members(value: Any, path: Path, max_label: int) -> list[np.ndarray]:
    if not isinstance(value, list):
        raise InputError(f"{path}: labels must be a cell array (one list of superpixel labels per candidate)")
    members = []
    for i, item in enumerate(value):
        labels = np.asarray(item).reshape(-1)
        if labels.size == 0 or labels.dtype.kind not in "fiu" or labels.min() < 1 or labels.max() > max_label:
            raise InputError(f"{path}: labels{{{i + 1}}} must be superpixel labels in [1, {max_label}]")
        members.append(labels.astype(np.int32))
    return members


def _csr(members: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices) of a list of member arrays."""
    indptr = np.concatenate([[0], np.cumsum([len(m) for m in members], dtype=np.int64)]).astype(np.int64)
    return indptr, np.concatenate([np.zeros(0, np.int32), *members]).astype(np.int32)
