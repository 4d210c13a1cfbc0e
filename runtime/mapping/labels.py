"""Labels drawn once for a whole recording: world boxes -> each posed frame's ground truth.

An annotator draws each object once, as a box in the gravity-aligned world (world_boxes.json);
every posed frame then gets its ground truth in the README's format (docs/mapping.md "Labels drawn
once"):

* ``box3d``: the world box moved into the frame's camera (a3d.runtime.mapping.world), with the
  frame's ``R_tilt`` derived from its pose (the world is gravity-aligned, y down);
* whether the frame sees it: the frame's depth points that fall inside the box are its *seen*
  pixels. A box grown by ``margin_m`` takes the depth noise, and its bottom is raised by
  ``floor_gap_m`` so that the floor (or the table top) an object stands on is not taken for it.
  An object with at least ``min_seen_px`` seen pixels gets an entry (a3d-synth annotates objects
  with at least 50 visible pixels, the default); the others, none;
* ``visibility``: seen pixels over the pixels of the box's projection inside the image (the
  *expected* pixels), for the record (labels.jsonl), not for the decision;
* ``box2d_visible``: the extent of the seen pixels; ``box2d_amodal``: the projected box, clipped
  to the image (``geometry.project_boxes_to_2d``, as a3d-synth computes it);
* an instance map of the seen pixels (a pixel inside several boxes goes to the smallest box).

Assumption: the scene is static (the same boxes in every frame) and the poses are right; a
moved object or a drifting pose gives wrong labels, which the seen-pixel count cannot tell.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.mapping.world import boxes_to_camera
from a3d.runtime.mapping.world_boxes import WorldBoxes
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import (
    Intrinsics,
    backproject_depth,
    box_edges_clipped,
    boxes_from_pixel_bounds,
    pixel_window,
    points_in_box,
    project_boxes_to_2d,
    project_points,
)


@dataclass(frozen=True)
class LabelConfig:
    """``min_seen_px``: seen pixels an object needs for an entry; ``margin_m``: the box grown by
    this for the depth's noise; ``floor_gap_m``: its bottom raised by this (module docstring)."""

    min_seen_px: int = 50
    margin_m: float = 0.03
    floor_gap_m: float = 0.02
    fill_holes: bool = True


@dataclass(frozen=True)
class FrameLabels:
    """One frame's labels: ``truth`` (the seen objects, in world order), ``ids`` their world ids,
    ``instances`` (H, W) uint16 (k = the k-th object of ``truth``); per world object ``boxes3d``
    (N, 7) in the camera, ``seen_px`` and ``expected_px`` (0 for a box outside the image)."""

    truth: GroundTruth
    ids: np.ndarray
    instances: np.ndarray
    boxes3d: np.ndarray
    seen_px: np.ndarray
    expected_px: np.ndarray

    @property
    def visibility(self) -> np.ndarray:
        """Seen over expected pixels per world object (0 where none are expected)."""
        return np.where(self.expected_px > 0, self.seen_px / np.maximum(self.expected_px, 1e-9), 0.0)


def label_frame(
    world: WorldBoxes,
    pose: np.ndarray,
    R_tilt: np.ndarray,
    depth: np.ndarray,
    K: Intrinsics,
    config: LabelConfig = LabelConfig(),
) -> FrameLabels:
    """The labels of one frame (module docstring): ``pose`` its camera-to-world transform,
    ``R_tilt`` its gravity (from the pose), ``depth`` (H, W) metres, 0 = missing."""
    size = depth.shape
    boxes = boxes_to_camera(world.boxes, pose, R_tilt)
    amodal = project_boxes_to_2d(boxes, R_tilt, K, size)
    expected = projected_areas(boxes, R_tilt, K, size)
    filled = fill_depth(depth) if config.fill_holes else depth
    tilt_points = backproject_depth(filled, K) @ R_tilt.T
    valid = filled > 0
    masks: dict[int, tuple[np.ndarray, tuple[slice, slice]]] = {}
    seen = np.zeros(len(boxes), np.int64)
    for i in np.flatnonzero(expected > 0):
        window = pixel_window(amodal[i], size)
        inside = valid[window] & inside_box(tilt_points[window], boxes[i], R_tilt, config)
        seen[i] = int(inside.sum())
        if seen[i] >= config.min_seen_px:
            masks[int(i)] = (inside, window)
    keep = sorted(masks)
    instances = np.zeros(size, np.uint16)
    for i in sorted(keep, key=lambda k: -float(np.prod(boxes[k, 3:6]))):  # the smallest box paints last
        inside, window = masks[i]
        instances[window][inside] = keep.index(i) + 1
    visible = np.array([_pixel_box(*masks[i]) for i in keep]).reshape(-1, 4)
    truth = GroundTruth.from_classes(
        [world.classes[i] for i in keep], boxes[keep], visible, amodal[keep], np.arange(1, len(keep) + 1)
    )
    return FrameLabels(truth, world.ids[keep], instances, boxes, seen, expected)


def projected_areas(
    boxes: np.ndarray, R_tilt: np.ndarray, K: Intrinsics, size: tuple[int, int]
) -> np.ndarray:
    """(N,) pixel area of each box's projection (the convex hull of its edges cut at the near
    plane) inside the image; 0 for a box wholly behind the camera or outside the image."""
    H_img, W_img = size
    image = np.array(
        [[-0.5, -0.5], [W_img - 0.5, -0.5], [W_img - 0.5, H_img - 0.5], [-0.5, H_img - 0.5]], np.float32
    )
    edges, valid = box_edges_clipped(boxes, R_tilt)
    areas = np.zeros(len(boxes))
    for i in np.flatnonzero(valid.any(axis=1)):
        points = project_points(edges[i][valid[i]].reshape(-1, 3), K)
        hull = cv2.convexHull(np.clip(points, -1e6, 1e6).astype(np.float32))
        area, _ = cv2.intersectConvexConvex(hull, image)
        areas[i] = max(float(area), 0.0)
    return areas


def inside_box(points: np.ndarray, box: np.ndarray, R_tilt: np.ndarray, config: LabelConfig) -> np.ndarray:
    """Which tilt-frame points (..., 3) lie in ``box`` (camera-frame centre) grown by the margin,
    its bottom raised by the floor gap (y is down in the tilt frame)."""
    return points_in_box(points, box, R_tilt, config.margin_m, -config.floor_gap_m)


def _pixel_box(inside: np.ndarray, window: tuple[slice, slice]) -> np.ndarray:
    """The 2D box of a window's marked pixels, in image coordinates."""
    rows, cols = np.nonzero(inside)
    bounds = [
        cols.min() + window[1].start,
        rows.min() + window[0].start,
        cols.max() + window[1].start,
        rows.max() + window[0].start,
    ]
    return boxes_from_pixel_bounds(bounds)
