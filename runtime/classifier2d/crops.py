"""Boxes of an image as one classifier batch: each box with some context, resized to the network's input.

Why: an ImageNet classifier saw whole objects with some background around them. Each box grows by
``context`` of its width and height on each side (clipped to the image) and is resized to ``side``
x ``side``, stretched: the classifier then judges what the box holds. A square about the box would
add more of the scene for a long thin box, and on the real frames of bench.real_frames it then
vouched for boxes on a strip of a desk as much as for the desk (docs/real-rooms.md).
"""

from __future__ import annotations

import cv2
import numpy as np

CONTEXT = 0.1  # of the box's width and height, on each side


def crop_batch(image_rgb: np.ndarray, boxes: np.ndarray, side: int, context: float = CONTEXT) -> np.ndarray:
    """(N, 3, side, side) float32 RGB ``(value - 128) / 128`` of the (N, 4) [x1, y1, x2, y2] boxes
    (pixels) of an (H, W, 3) uint8 RGB image; a box outside the image gives its nearest pixels."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    height, width = image_rgb.shape[:2]
    grown = boxes + context * np.tile(boxes[:, 2:] - boxes[:, :2], 2) * [-1, -1, 1, 1]
    left, top = (
        np.clip(np.floor(grown[:, i]), 0, limit - 1).astype(int) for i, limit in ((0, width), (1, height))
    )
    right = np.clip(np.ceil(grown[:, 2]).astype(int), left + 1, width)
    bottom = np.clip(np.ceil(grown[:, 3]).astype(int), top + 1, height)
    batch = np.empty((len(boxes), side, side, 3), np.uint8)
    for i in range(len(boxes)):
        crop = image_rgb[top[i] : bottom[i], left[i] : right[i]]
        flags = cv2.INTER_AREA if max(crop.shape[:2]) > side else cv2.INTER_LINEAR
        batch[i] = cv2.resize(crop, (side, side), interpolation=flags)
    return np.ascontiguousarray(((batch.astype(np.float32) - 128.0) / 128.0).transpose(0, 3, 1, 2))
