"""Training-time colour and depth augmentation (``data.augment``, off by default).

Rendering a frame again under other light or through another sensor is costly; changing the
colour and depth the network sees is not, and covers much of the gap between cameras: exposure
(up to 0.7 stop either way), white balance, contrast and saturation, blur, sensor noise and JPEG
re-compression for colour; for depth (before the holes are filled) noise that grows with the
square of the depth, coarser quantisation, and holes in clumps. Nothing moves: the boxes, the
proposals and the regression targets stay valid. The generator of each image is seeded by
(solver seed, iteration, image slot), so a resumed run sees the very same batches.
"""

from __future__ import annotations

import cv2
import numpy as np


def augment_rng(seed: int, iteration: int, slot: int) -> np.random.Generator:
    """The generator of image ``slot`` of the mini-batch of ``iteration``."""
    return np.random.default_rng(np.random.SeedSequence([seed, iteration, slot, 0xA06]))


def augment_colour(rng: np.random.Generator, color: np.ndarray) -> np.ndarray:
    """uint8 BGR (H, W, 3) -> the same image under other exposure, white balance and camera."""
    img = color.astype(np.float32) / 255.0
    linear = img**2.2 * (2.0 ** rng.uniform(-0.7, 0.7)) * rng.uniform(0.85, 1.15, 3).astype(np.float32)
    img = np.clip(linear, 0, 1) ** (1 / 2.2)
    grey = img.mean(axis=2, keepdims=True)
    img = grey + (img - grey) * rng.uniform(0.7, 1.3)
    img = 0.5 + (img - 0.5) * rng.uniform(0.8, 1.2)
    if rng.random() < 0.4:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, 1.2)))
    img = img + rng.normal(0.0, rng.uniform(0.0, 0.03), img.shape).astype(np.float32)
    out = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
    if rng.random() < 0.5:
        _, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(40, 95))])
        out = cv2.imdecode(data, cv2.IMREAD_COLOR)
    return out


def augment_depth(rng: np.random.Generator, depth: np.ndarray) -> np.ndarray:
    """float32 metres (H, W), 0 = missing -> with more noise, coarser steps and more holes."""
    H, W = depth.shape
    valid = depth > 0
    out = depth + (rng.uniform(0.0, 0.004) * depth * depth * rng.standard_normal((H, W))).astype(np.float32)
    if rng.random() < 0.5:  # quantisation to steps of 1-2% of the depth (a coarser disparity)
        step = float(rng.uniform(0.01, 0.02))
        out = np.exp(np.round(np.log(np.maximum(out, 1e-3)) / step) * step).astype(np.float32)
    holes = np.zeros((H, W), np.uint8)
    for _ in range(int(rng.poisson(4))):
        centre = (int(rng.integers(W)), int(rng.integers(H)))
        axes = (int(rng.integers(2, max(3, W // 12))), int(rng.integers(2, max(3, H // 12))))
        cv2.ellipse(holes, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return np.where(valid & (holes == 0), out, 0.0).astype(np.float32)


def augment_frame(
    rng: np.random.Generator, color: np.ndarray, depth: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Colour and depth of one training image, augmented (see the module docstring)."""
    return augment_colour(rng, color), augment_depth(rng, depth)
