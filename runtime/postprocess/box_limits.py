"""Boxes that can exist: decoded 3D boxes are bounded before they are written.

The 3D regressor is unbounded: a wild output can put a box's centre behind the camera or give
it a size no object of its class has. Decoded boxes are therefore clamped, and what that
changed that a user would see goes into the frame's detections line (``notes``):

- the centre's depth z to at least ``near_m``: the frame's near range, the least valid raw depth
  (no seen surface is nearer, so no centre of a seen object is, short of one reaching out of the
  image toward the camera), never below ``MIN_NEAR_M``; a centre at least ``SLIDE_FROM`` of the
  near range in front of the camera is moved along its viewing ray (the box still projects where
  the network put it), a nearer one only has its z set (sliding it would throw it far sideways);
- each size l, w, h to ``[MIN_SIZE_M, max of the class's family]``: the family bounds are
  generous (the largest objects of SUN RGB-D / NYUv2 annotations of each kind fit with room to
  spare) so that only regressions that went wrong are touched.

A clamped centre is routine on the tail of a frame's detections: of the ~200 written per frame,
a few scoring below 0.01 regress in front of every seen surface (each bundled sample frame has
1 to 15, none scoring 0.01). The clamp keeps those boxes valid; only a clamped centre of a
detection scoring at least ``SHOW_THRESHOLD`` (one a user is shown) is a note, since that is a
confident regression gone wrong. A clamped size is rare at these bounds and always a note.

Class families and their largest size (metres):

- ``large`` furniture, 6.0: bathtub, bed, bookshelf, counter, desk, door, dresser, sofa, table;
- ``small`` objects, 2.5: box, chair, garbage bin, lamp, monitor, night stand, pillow, sink,
  television, toilet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from a3d.runtime.postprocess.score_calibration import SHOW_THRESHOLD
from a3d.runtime.structures.boxes import CENTER, SIZE, Z, boxes_array
from a3d.runtime.structures.classes import CLASSES

MIN_NEAR_M = 0.1
MIN_SIZE_M = 0.02
SLIDE_FROM = 0.25  # centres nearer than this share of the near range are not slid along their ray
FAMILY_MAX_SIZE_M = {"large": 6.0, "small": 2.5}
LARGE_CLASSES = frozenset(
    {"bathtub", "bed", "bookshelf", "counter", "desk", "door", "dresser", "sofa", "table"}
)
CLASS_MAX_SIZE_M = np.array(
    [FAMILY_MAX_SIZE_M["large" if name in LARGE_CLASSES else "small"] for name in CLASSES]
)


@dataclass(frozen=True, eq=False)
class BoundedBoxes:
    """``boxes3d`` (K, 7) within the limits; which boxes had their centre or a size clamped."""

    boxes3d: np.ndarray
    centres: np.ndarray  # (K,) bool: the centre was clamped
    sizes: np.ndarray  # (K,) bool: a size was clamped

    @property
    def centres_clamped(self) -> int:
        return int(self.centres.sum())

    @property
    def sizes_clamped(self) -> int:
        return int(self.sizes.sum())

    def reordered(self, order: np.ndarray) -> BoundedBoxes:
        """The same boxes in ``order`` (the detections re-sorted by a changed score)."""
        return BoundedBoxes(self.boxes3d[order], self.centres[order], self.sizes[order])

    def notes(self, scores: np.ndarray) -> list[str]:
        """The line's notes for what was clamped (module docstring): centres of detections whose
        ``scores`` reach SHOW_THRESHOLD, and every size; none when nothing was."""
        notes = []
        shown = int((self.centres & (np.asarray(scores) >= SHOW_THRESHOLD)).sum())
        if shown:
            notes.append(
                f"{shown} box centres scoring >= {SHOW_THRESHOLD} clamped to the near range of the depth"
            )
        if self.sizes_clamped:
            notes.append(f"{self.sizes_clamped} boxes with a size clamped to their class family's bounds")
        return notes


def near_range(depth: np.ndarray) -> float:
    """The frame's near range (metres): the least valid raw depth, at least MIN_NEAR_M."""
    valid = depth[depth > 0]
    return max(MIN_NEAR_M, float(valid.min())) if valid.size else MIN_NEAR_M


def bound_boxes(boxes3d: np.ndarray, class_idx: np.ndarray, near_m: float) -> BoundedBoxes:
    """Clamp (K, 7) camera-frame boxes of 0-based classes ``class_idx``; see the module docstring."""
    boxes = boxes_array(boxes3d).copy()
    z = boxes[:, Z]
    behind = z < near_m
    ahead = behind & (z >= SLIDE_FROM * near_m)
    boxes[ahead, CENTER] *= (near_m / z[ahead])[:, None]  # slide along the ray to depth near_m
    boxes[behind & ~ahead, Z] = near_m
    upper = CLASS_MAX_SIZE_M[np.asarray(class_idx, np.int64)][:, None]
    sizes = boxes[:, SIZE]
    bounded = np.clip(sizes, MIN_SIZE_M, upper)
    resized = (bounded != sizes).any(axis=1)
    boxes[:, SIZE] = bounded
    return BoundedBoxes(boxes, behind, resized)
