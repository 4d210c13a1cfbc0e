"""A result drawn on its image with OpenCV: what the rerun view's camera panel shows, without rerun.

Each detection's 2D box (the proposal box it was scored on) with its label "class score" and,
where the camera is known, its 3D box projected into the image, in the class colours the view
uses (``CLASS_COLORS_RGB``); the shapes come from a3d.runtime.viewer.shapes, as the view's do.
"""

from __future__ import annotations

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.structures.classes import CLASS_COLORS_RGB
from a3d.runtime.structures.geometry import BOX_EDGES, Intrinsics
from a3d.runtime.viewer.shapes import box_labels, projected_box_edges

SHIFT = 4  # cv2's fixed-point bits: segments are drawn to 1/16 pixel
FONT = cv2.FONT_HERSHEY_SIMPLEX


def draw_detections(
    image: np.ndarray,
    class_ids: np.ndarray,
    scores: np.ndarray,
    boxes2d: np.ndarray,
    *,
    boxes3d: np.ndarray | None = None,
    R_tilt: np.ndarray | None = None,
    K: Intrinsics | None = None,
    bgr: bool = False,
) -> np.ndarray:
    """A copy of ``image`` ((H, W, 3) uint8, RGB or with ``bgr`` BGR) with the detections drawn on
    it: 2D boxes and labels, and the 3D boxes (camera frame, yaw in the tilt frame of ``R_tilt``)
    projected with ``K`` when all three are given."""
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"image: expected an (H, W, 3) uint8 array, got {got}")
    out = np.ascontiguousarray(image).copy()
    height, width = out.shape[:2]
    colours = [CLASS_COLORS_RGB[c][::-1] if bgr else CLASS_COLORS_RGB[c] for c in class_ids]
    line = max(1, round(min(height, width) / 240))
    if boxes3d is not None and R_tilt is not None and K is not None and len(boxes3d):
        segments = projected_box_edges(boxes3d, R_tilt, K, (height, width))
        for k, segment in enumerate(segments):
            if np.isfinite(segment).all():
                a, b = (tuple(int(v) for v in np.round(p * (1 << SHIFT))) for p in segment)
                cv2.line(out, a, b, colours[k // len(BOX_EDGES)], 1, cv2.LINE_AA, SHIFT)
    for box, label, colour in zip(boxes2d, box_labels(class_ids, scores), colours, strict=True):
        # Box edges are pixel edges (README "Pixels and 2D boxes"): the outermost pixels inside it.
        x1, y1, x2, y2 = (round(float(v)) for v in (box[0] + 0.5, box[1] + 0.5, box[2] - 0.5, box[3] - 0.5))
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, line)
        _label(out, label, (x1, y1), colour)
    return out


def _label(image: np.ndarray, text: str, corner: tuple[int, int], colour: tuple[int, ...]) -> None:
    """``text`` in white on a box of ``colour`` just above ``corner`` (inside the image)."""
    scale = max(0.4, min(image.shape[:2]) / 960)
    (w, h), base = cv2.getTextSize(text, FONT, scale, 1)
    x = min(max(corner[0], 0), max(0, image.shape[1] - w))
    y = max(corner[1], h + base)
    cv2.rectangle(image, (x, y - h - base), (x + w, y), colour, cv2.FILLED)
    cv2.putText(image, text, (x, y - base), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
