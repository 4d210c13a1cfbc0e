"""Network input tensors from a colour image and a hole-filled depth map (docs/conventions.md "Network").

Training (a3d.train) and the runtime both build their inputs here, so the constants cannot drift.
Both functions return float32 arrays in CHW layout at the image's native size.
"""

from __future__ import annotations

import numpy as np

COLOR_MEAN_BGR = np.array([102.98, 115.95, 122.77], dtype=np.float32)
"""Per-channel mean (B, G, R order, 0..255 scale) subtracted from the colour trunk's input."""

DEPTH_MEAN = 72.81
"""Mean subtracted from the scaled depth (0..255 scale) of the depth trunk's input."""

DEPTH_TRUNCATION_M = 10.0
"""Depth (metres) mapped to 255. The authors' release truncates at 10 m; the paper says 8 m."""


def color_input(bgr: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR -> (3, H, W) float32 BGR minus COLOR_MEAN_BGR (no scaling, as in VGG16/Caffe)."""
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ValueError(f"color_input: expected (H, W, 3) uint8 BGR, got {bgr.shape} {bgr.dtype}")
    out = bgr.astype(np.float32) - COLOR_MEAN_BGR
    return np.ascontiguousarray(out.transpose(2, 0, 1))


def depth_input(filled_depth_m: np.ndarray, truncation: float = DEPTH_TRUNCATION_M) -> np.ndarray:
    """(H, W) hole-filled depth in metres -> (3, H, W) float32 depth-trunk input.

    Depth is clipped to [0, truncation], scaled so that `truncation` maps to 255, minus DEPTH_MEAN,
    and replicated to 3 channels (the trunk is an ImageNet VGG16). Values are not rounded to
    8 bits: the release stores 8-bit images, but rounding only adds quantisation noise.
    """
    if filled_depth_m.ndim != 2:
        raise ValueError(f"depth_input: expected an (H, W) depth map, got shape {filled_depth_m.shape}")
    if not truncation > 0:
        raise ValueError(f"depth_input: truncation must be positive, got {truncation}")
    scaled = np.clip(filled_depth_m.astype(np.float32), 0.0, truncation) * np.float32(255.0 / truncation)
    scaled -= np.float32(DEPTH_MEAN)
    return np.ascontiguousarray(np.broadcast_to(scaled, (3, *scaled.shape)))
