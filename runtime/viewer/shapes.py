"""What the view shows, computed without rerun: the options, the labels and the projected boxes.

Both renderers take their shapes from here: the rerun view (a3d.runtime.viewer.view, an optional
extra) and the OpenCV drawing of a result (a3d.runtime.viewer.draw), so a box looks the same,
with the same label and colour (``CLASS_COLORS_RGB``), in a recording and in a drawn image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.structures.boxes import boxes_array
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import Intrinsics, box_edges_clipped, project_points


@dataclass(frozen=True)
class ViewOptions:
    """What to draw besides the detections; the cloud stride trades detail for viewer load."""

    cloud_stride: int = 2
    show_ground_truth: bool = True
    max_proposals: int = 0
    min_score: float = 0.0  # detections below this score are written to the JSON but not drawn


def box_labels(class_ids: np.ndarray, scores: np.ndarray) -> list[str]:
    """"class score" per detection, the label every renderer writes beside a box."""
    return [f"{CLASSES[c]} {s:.2f}" for c, s in zip(class_ids, scores, strict=True)]


def label_anchors(boxes2d: np.ndarray) -> np.ndarray:
    """(N, 2) top-centre of each XYXY box: rerun centres a point's label just below the point, so
    the label reads as the box's title, inside it, even for a box that reaches the image's bottom."""
    boxes = np.asarray(boxes2d, dtype=np.float64).reshape(-1, 4)
    return np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 1]], axis=1)


def projected_box_edges(
    boxes: np.ndarray, R_tilt: np.ndarray, K: Intrinsics, image_size: tuple[int, int] | None = None
) -> np.ndarray:
    """Image-space segments (N*12, 2, 2) of the boxes' edges, clipped at the near plane and, when
    ``image_size`` (H, W) is given, to the image (so the 2D view's auto-fit frames the image).

    Edges wholly behind the near plane or outside the image come back as NaN segments.
    """
    seg, valid = box_edges_clipped(boxes_array(boxes), R_tilt)
    uv = project_points(seg, K).reshape(-1, 2, 2)
    uv[~valid.reshape(-1)] = np.nan
    return uv if image_size is None else clip_segments(uv, image_size)


def clip_segments(segments: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Liang-Barsky clipping of 2D segments (S, 2, 2) to the image [-0.5, W-0.5] x [-0.5, H-0.5];
    segments wholly outside become NaN."""
    height, width = image_size
    p0, d = segments[:, 0], segments[:, 1] - segments[:, 0]
    lo, hi = np.zeros(len(segments)), np.ones(len(segments))
    bounds = ((-0.5, width - 0.5), (-0.5, height - 0.5))
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, (low, high) in enumerate(bounds):
            for edge, sign in ((low, -1.0), (high, 1.0)):
                p, q = sign * d[:, axis], sign * (edge - p0[:, axis])
                t = q / p
                outside = (p == 0) & (q < 0)
                lo = np.where(p < 0, np.maximum(lo, t), lo)
                hi = np.where(p > 0, np.minimum(hi, t), hi)
                lo = np.where(outside, np.inf, lo)
    kept = lo <= hi  # inf * 0 (a segment outside, parallel to a border) never reaches the product
    out = np.full_like(segments, np.nan, dtype=np.float64)
    p0, d, lo, hi = p0[kept], d[kept], lo[kept, None], hi[kept, None]
    out[kept] = np.stack([p0 + lo * d, p0 + hi * d], axis=1)
    return out
