"""From the network's per-RoI outputs to detections (docs/conventions.md "Inference and post-processing").

Per class: the ``top_k`` best-scoring proposals (the release keeps at most 100 per class and
image), then greedy 2D NMS at ``nms_iou`` on the proposal boxes; no NMS in 3D, no pruning by
size. Each kept detection gets its class-specific 3D box, decoded from the class's initial box
(lifted centre, class mean size, theta 0) with a3d.runtime.postprocess.box_coder.decode_3d and made canonical
(l >= w, theta in [-pi/2, pi/2]), and its amodal 2D box, decoded from the proposal box with the
2D regressor's deltas (box_coder.decode_2d) and clipped to the image like the ground truth's.

Indices: ``class_idx`` is 0-based into CLASSES; the network's softmax and delta rows are indexed
``class_idx + 1`` (index 0 is background).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.frontend.lifting import initial_boxes
from a3d.runtime.postprocess.box_coder import decode_2d, decode_3d
from a3d.runtime.structures.geometry import batched_nms_2d, canonical_boxes


def select_detections(
    scores: np.ndarray, boxes2d: np.ndarray, top_k: int, min_score: float, nms_iou: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-class top-k, score threshold, then per-class greedy 2D NMS.

    ``scores`` (N, C) object-class scores (the softmax without its background column),
    ``boxes2d`` (N, 4) the proposal boxes. A candidate is dropped when its IoU with a kept,
    better-scored candidate of its class is > ``nms_iou`` (a3d.runtime.structures.geometry.nms_2d's rule);
    ties in score go to the lower proposal index. Returns (rows (K,) proposal indices,
    class_idx (K,), scores (K,)) by descending score (ties: class order, then rank).
    """
    scores = np.asarray(scores, np.float64)
    boxes2d = np.asarray(boxes2d, np.float64).reshape(-1, 4)
    n, c = scores.shape
    k = min(int(top_k), n)
    if k <= 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    rows = np.argsort(-scores, axis=0, kind="stable")[:k].T.reshape(-1)  # class-major, best first
    classes = np.repeat(np.arange(c, dtype=np.int64), k)
    cand = scores[rows, classes]
    alive = cand >= min_score
    rows, classes, cand = rows[alive], classes[alive], cand[alive]
    keep = batched_nms_2d(boxes2d[rows], cand, classes, nms_iou)
    return rows[keep], classes[keep], cand[keep]


def decode_detections(
    rows: np.ndarray,
    class_idx: np.ndarray,
    centers: np.ndarray,
    mean_sizes: np.ndarray,
    proposal_boxes: np.ndarray,
    deltas3d: np.ndarray,
    deltas2d: np.ndarray,
    image_size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Class-specific boxes of the selected detections: (boxes3d (K, 7) canonical, amodal boxes2d (K, 4)).

    ``centers`` (N, 3) lifted proposal centres (camera frame, metres), ``mean_sizes`` (C, 3)
    class mean [l, w, h], ``proposal_boxes`` (N, 4) native pixels, ``deltas3d`` (N, C + 1, 7) and
    ``deltas2d`` (N, C + 1, 4) raw network deltas, ``image_size`` (H, W). The 2D deltas are
    invariant to the resize between native and network pixels, so they decode on native boxes.
    """
    rows = np.asarray(rows, np.int64)
    class_idx = np.asarray(class_idx, np.int64)
    if len(rows) == 0:
        return np.zeros((0, 7)), np.zeros((0, 4))
    initial = initial_boxes(np.asarray(centers)[rows], mean_sizes)[np.arange(len(rows)), class_idx]
    boxes3d = canonical_boxes(decode_3d(initial, np.asarray(deltas3d)[rows, class_idx + 1]))
    proposals = np.asarray(proposal_boxes, np.float64)[rows]
    amodal = decode_2d(proposals, np.asarray(deltas2d)[rows, class_idx + 1])
    height, width = image_size
    limits = np.array([width - 0.5, height - 0.5, width - 0.5, height - 0.5])
    return boxes3d, np.clip(amodal, -0.5, limits)
