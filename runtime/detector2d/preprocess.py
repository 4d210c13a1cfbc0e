"""An RGB image as each layout's graph takes it, and the scale back to the image's pixels.

Why: a detector only finds what it was trained to see in the form it saw it. YOLOX takes BGR
values unscaled, letterboxed at the top-left on grey 114 (its demo's preproc); NanoDet takes BGR
normalised by ImageNet's mean and std (its own constants), letterboxed on black; a boxes-layout
graph takes RGB scaled to 0..1, resized to its input size (stretched, as torchvision's and
RT-DETR's exports expect) or as it is when the graph takes any size.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.detector2d.layouts import BOXES, NANODET, YOLOX, Layout


@dataclass(frozen=True)
class InputConvention:
    """How a layout's graph wants its image: channel order, fit, and ``(value - mean) / std``."""

    bgr: bool
    pad: float | None  # letterbox fill; None: stretched to the input size
    mean: tuple[float, float, float]  # in the graph's channel order
    std: tuple[float, float, float]


CONVENTIONS: dict[str, InputConvention] = {
    YOLOX: InputConvention(True, 114.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
    NANODET: InputConvention(True, 0.0, (103.53, 116.28, 123.675), (57.375, 57.12, 58.395)),
    BOXES: InputConvention(False, None, (0.0, 0.0, 0.0), (255.0, 255.0, 255.0)),
}


def letterbox(image: np.ndarray, size: tuple[int, int], pad: float) -> tuple[np.ndarray, float]:
    """``image`` resized by r = min(height / h, width / w) into the top-left of a ``size``
    (height, width) canvas filled with ``pad``; (canvas, r)."""
    h, w = image.shape[:2]
    r = min(size[0] / h, size[1] / w)
    new_w, new_h = max(1, int(w * r)), max(1, int(h * r))  # floor, as YOLOX's preproc
    canvas = np.full((*size, image.shape[2]), pad, image.dtype)
    canvas[:new_h, :new_w] = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    return canvas, r


def network_input(image_rgb: np.ndarray, layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """(the graph's float32 input, (sx, sy, sx, sy): network pixels per image pixel) for an
    (H, W, 3) uint8 RGB image."""
    convention = CONVENTIONS[layout.kind]
    image = image_rgb[..., ::-1] if convention.bgr else image_rgb
    h, w = image.shape[:2]
    if layout.input_size is None:
        fitted, scale = image, (1.0, 1.0)
    elif convention.pad is None:
        height, width = layout.input_size
        fitted = cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR)
        scale = (width / w, height / h)
    else:
        fitted, r = letterbox(np.ascontiguousarray(image), layout.input_size, convention.pad)
        scale = (r, r)
    tensor = fitted.transpose(2, 0, 1).astype(np.float32)  # channels first while still bytes
    if convention.mean != (0.0, 0.0, 0.0) or convention.std != (1.0, 1.0, 1.0):
        mean, std = (np.asarray(v, np.float32)[:, None, None] for v in (convention.mean, convention.std))
        tensor = (tensor - mean) / std
    tensor = np.ascontiguousarray(tensor[None] if layout.batched else tensor)
    return tensor, np.asarray(scale * 2, np.float64)
