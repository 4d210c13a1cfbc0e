"""RoIs that look like a 2D detector's boxes, so that the network learns the 3D box from them too.

The bundled pipeline ``real`` hands the network a COCO detector's boxes (a3d.runtime.detector2d),
each with an initial centre from the depth layer inside it (a3d.runtime.frontend.box_pixels),
while training shows it only ground-truth segments and segment proposals, lifted from their own
pixels. With ``data.detector_rois`` N, each visible ground-truth box of a training frame gives N
boxes jittered as a detector errs: the centre shifted and each side scaled by a few tenths of the
box (normal in the shift, log-normal in the scale), and one box in three stretched downwards over
some floor, as a detector's box of a chair or a table often is. Each is lifted as the runtime
lifts a detector's box (the reach of the ground truth's class) and labelled as every RoI is
(a3d.train.roidb.label_rois): those still at 2D IoU >= ``data.fg_iou`` with an object are its
foreground, the others background. The jitter is a pure function of the frame's name and the
seed, so the RoI database is the same on every run.
"""

from __future__ import annotations

import zlib

import numpy as np

from a3d.runtime.frontend.box_pixels import class_reach, lift_boxes
from a3d.runtime.structures.classes import NUM_CLASSES
from a3d.runtime.structures.geometry import CameraLike

SHIFT = 0.1  # std of the centre's shift, in box widths / heights
SCALE = 0.2  # std of the log of each side's scale
FLOOR_SHARE = 1 / 3  # share of the boxes stretched downwards
FLOOR = 0.2  # the most they are stretched, in box heights


def jittered_boxes(
    visible: np.ndarray, count: int, image_size: tuple[int, int], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` detector-like boxes per visible box ((G, 4) xyxy pixels), clipped to the image:
    (boxes (G * count, 4), the visible box each came from (G * count,))."""
    visible = np.asarray(visible, np.float64).reshape(-1, 4)
    source = np.repeat(np.arange(len(visible)), count)
    box = visible[source]
    size = box[:, 2:] - box[:, :2]
    centre = 0.5 * (box[:, :2] + box[:, 2:]) + rng.normal(0.0, SHIFT, size.shape) * size
    half = 0.5 * size * np.exp(rng.normal(0.0, SCALE, size.shape))
    out = np.concatenate([centre - half, centre + half], axis=1)
    floor = rng.random(len(out)) < FLOOR_SHARE
    out[floor, 3] += rng.uniform(0.0, FLOOR, floor.sum()) * size[floor, 1]
    height, width = image_size
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], -0.5, width - 0.5)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], -0.5, height - 0.5)
    keep = (out[:, 2] - out[:, 0] >= 2.0) & (out[:, 3] - out[:, 1] >= 2.0)
    return out[keep], source[keep]


def detector_like_rois(
    name: str,
    visible: np.ndarray,
    class_ids: np.ndarray,
    count: int,
    seed: int,
    depth_raw: np.ndarray,
    depth_filled: np.ndarray,
    K: CameraLike,
    mean_sizes: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame ``name``'s detector-like RoIs from its visible boxes ((G, 4)) of ``class_ids``
    ((G,) 0-based): (boxes (M, 4), lifted centres (M, 3), valid (M,) where a box held depth)."""
    rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
    boxes, source = jittered_boxes(visible, count, depth_filled.shape, rng)
    if not len(boxes):
        return boxes, np.zeros((0, 3)), np.zeros(0, bool)
    candidates = np.eye(NUM_CLASSES, dtype=bool)[np.asarray(class_ids, np.int64)[source]]
    lifted = lift_boxes(boxes, class_reach(candidates, mean_sizes), depth_raw, depth_filled, K)
    return boxes, lifted.centers, lifted.valid
