"""A detector's raw outputs as boxes, scores and class indices in network-input pixels.

Why: each export leaves a different amount of the decoding to its user; these are the three
decodings (a3d.runtime.detector2d.layouts), each a pure function of the arrays, so each is tested
against outputs crafted by hand. Thresholds, the class map and NMS come after, the same for all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from a3d.runtime.detector2d.layouts import BOXES, NANODET, YOLOX, Layout


@dataclass(frozen=True)
class Decoded:
    """One box per candidate: (A, 4) float64 xyxy in network-input pixels, (A,) scores, (A,) int64
    detector class indices."""

    boxes: np.ndarray
    scores: np.ndarray
    labels: np.ndarray


def decode(layout: Layout, outputs: list[np.ndarray]) -> Decoded:
    """The outputs of ``layout``'s graph (in ``layout.outputs``' order), decoded."""
    if layout.kind == YOLOX:
        return decode_yolox(outputs[0], layout.input_size, layout.strides)
    if layout.kind == NANODET:
        levels = len(layout.strides)
        return decode_nanodet(outputs[:levels], outputs[levels:], layout.input_size, layout.strides)
    if layout.kind == BOXES:
        return decode_boxes(*outputs)
    raise ValueError(f"unknown 2D detector layout {layout.kind!r}")


def grid(size: tuple[int, int], strides: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Every cell of every stride's feature map over an input of ``size`` (height, width), row-major
    and finest stride first: ((A, 2) cell column and row, (A,) stride)."""
    cells, cell_strides = [], []
    for stride in strides:
        rows, cols = math.ceil(size[0] / stride), math.ceil(size[1] / stride)
        y, x = np.mgrid[:rows, :cols]
        cells.append(np.stack([x.ravel(), y.ravel()], axis=1))
        cell_strides.append(np.full(rows * cols, stride))
    return np.concatenate(cells).astype(np.float64), np.concatenate(cell_strides).astype(np.float64)


def decode_yolox(output: np.ndarray, size: tuple[int, int], strides: tuple[int, ...]) -> Decoded:
    """YOLOX's raw grid (1, A, 5 + C): centre (raw + cell) * stride, size exp(raw) * stride, then
    objectness and C class probabilities; each cell's score is objectness x its best class's."""
    raw = np.asarray(output, np.float64).reshape(output.shape[-2], output.shape[-1])
    cells, stride = grid(size, strides)
    centre = (raw[:, :2] + cells) * stride[:, None]
    half = np.exp(raw[:, 2:4]) * stride[:, None] / 2
    labels = raw[:, 5:].argmax(axis=1)
    scores = raw[:, 4] * raw[np.arange(len(raw)), 5 + labels]
    return Decoded(np.concatenate([centre - half, centre + half], axis=1), scores, labels.astype(np.int64))


def decode_nanodet(
    class_maps: list[np.ndarray], distribution_maps: list[np.ndarray], size: tuple[int, int],
    strides: tuple[int, ...],
) -> Decoded:  # fmt: skip
    """NanoDet's GFL head, per stride (finest first): class probabilities (1, HW, C) (the sigmoid is
    in the graph) and (1, HW, 4 * bins) logits of the distances left, top, right, bottom from the
    cell centre ((cell + 0.5) * stride) in strides; a distance is its softmax's mean bin."""
    probs = np.concatenate([np.asarray(m, np.float64).reshape(-1, m.shape[-1]) for m in class_maps])
    logits = np.concatenate([np.asarray(m, np.float64).reshape(-1, m.shape[-1]) for m in distribution_maps])
    bins = logits.shape[1] // 4
    logits = logits.reshape(-1, 4, bins)
    weights = np.exp(logits - logits.max(axis=2, keepdims=True))
    distances = (weights @ np.arange(bins)) / weights.sum(axis=2)
    cells, stride = grid(size, strides)
    centre = (cells + 0.5) * stride[:, None]
    distances *= stride[:, None]
    labels = probs.argmax(axis=1)
    boxes = np.concatenate([centre - distances[:, :2], centre + distances[:, 2:]], axis=1)
    return Decoded(boxes, probs[np.arange(len(probs)), labels], labels.astype(np.int64))


def decode_boxes(boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray) -> Decoded:
    """Boxes (N, 4) xyxy in input pixels, scores (N,) and integer labels (N,), with or without a
    leading batch dimension of 1."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    scores = np.asarray(scores, np.float64).reshape(-1)
    labels = np.asarray(labels).reshape(-1)
    if not (len(boxes) == len(scores) == len(labels)):
        counts = f"{len(boxes)} boxes, {len(scores)} scores and {len(labels)} labels"
        raise ValueError(f"the detector gave {counts}")
    return Decoded(boxes, scores, labels.astype(np.int64))
