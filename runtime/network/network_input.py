"""The network's image and RoI inputs at the model's input scale (numpy + OpenCV).

The trunks may run on a resized image (``input_scale``, e.g. 0.5 for the CPU models) while
proposals, lifting and every 3D quantity stay at native resolution; only the images and the RoIs
handed to the network are rescaled. Boxes follow the README pixel convention, so an image of
width ``W`` spans ``[-0.5, W - 0.5]`` and a resize by ``s`` maps ``x -> (x + 0.5) s - 0.5``.
"""

from __future__ import annotations

import cv2
import numpy as np

from a3d.runtime.network.preprocess import color_input, depth_input
from a3d.runtime.structures.geometry import context_boxes


def frame_network_inputs(
    color_bgr: np.ndarray,
    depth_filled: np.ndarray,
    boxes: np.ndarray,
    scale: float,
    truncation: float,
    context_scale: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Everything the network takes for one frame and its proposal boxes (N, 4, native pixels):
    colour and depth trunk inputs (3, h, w) float32 at ``scale`` (``network_inputs``), and the
    RoIs and context RoIs (N, 4) float32 in the resized image's pixels. The runtime and training
    (on flipped frames too) both build their inputs here, so they cannot drift apart."""
    color_small, depth_small = resize_to_scale(color_bgr, depth_filled, scale)
    return resized_network_inputs(
        color_small, depth_small, depth_filled.shape, boxes, truncation, context_scale
    )


def resized_network_inputs(
    color_small: np.ndarray,
    depth_small: np.ndarray,
    native_size: tuple[int, int],
    boxes: np.ndarray,
    truncation: float,
    context_scale: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``frame_network_inputs`` of a frame already resized by ``resize_to_scale`` (training caches
    the resized pair): ``native_size`` (H, W) is the frame's own, which the boxes are in."""
    h, w = depth_small.shape
    sx, sy = w / native_size[1], h / native_size[0]
    context = context_boxes(boxes, native_size, context_scale)
    rois = scale_boxes(boxes, sx, sy).astype(np.float32)
    color_in, depth_in = color_input(color_small), depth_input(depth_small, truncation)
    return color_in, depth_in, rois, scale_boxes(context, sx, sy).astype(np.float32)


def resize_to_scale(
    color_bgr: np.ndarray, depth_filled: np.ndarray, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Colour (H, W, 3) uint8 and hole-filled depth (H, W) float32 resized to ``round(W * scale) x
    round(H * scale)`` (at least 1); down-scaling averages areas (no aliasing), up-scaling is
    bilinear. The unchanged arrays (contiguous) where the size does not change."""
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"input scale must be a positive number, got {scale}")
    color_bgr, depth_filled = np.ascontiguousarray(color_bgr), np.ascontiguousarray(depth_filled)
    h, w = depth_filled.shape
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    if size == (w, h):
        return color_bgr, depth_filled
    interp = cv2.INTER_AREA if scale < 1.0 else cv2.INTER_LINEAR
    color_small = cv2.resize(color_bgr, size, interpolation=interp)
    return color_small, cv2.resize(depth_filled, size, interpolation=interp)


def network_inputs(
    color_bgr: np.ndarray, depth_filled: np.ndarray, scale: float, truncation: float
) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Colour and depth trunk inputs (3, h, w) float32 at ``scale`` and the exact (sx, sy) box scaling.

    ``color_bgr`` (H, W, 3) uint8, ``depth_filled`` (H, W) float32 metres (hole-filled);
    ``truncation`` metres map to 255 in the depth input (a3d.runtime.network.preprocess). The size is
    ``resize_to_scale``'s, so (sx, sy) = (w / W, h / H) differ slightly from ``scale``.
    """
    h, w = depth_filled.shape
    color_small, depth_small = resize_to_scale(color_bgr, depth_filled, scale)
    size = depth_small.shape
    return color_input(color_small), depth_input(depth_small, truncation), (size[1] / w, size[0] / h)


def scale_boxes(boxes: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Boxes (N, 4) in native pixel coordinates -> the resized image's: ``(b + 0.5) * s - 0.5``."""
    factors = np.array([sx, sy, sx, sy])
    return (np.asarray(boxes, np.float64).reshape(-1, 4) + 0.5) * factors - 0.5


def with_batch_index(boxes: np.ndarray, index: int) -> np.ndarray:
    """(N, 4) -> (N, 5) rows ``[index, x1, y1, x2, y2]``, the RoI layout of the training network."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    return np.concatenate([np.full((len(boxes), 1), float(index)), boxes], axis=1)
