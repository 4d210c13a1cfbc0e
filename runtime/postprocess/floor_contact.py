"""3D boxes of the classes that stand on the floor, reaching down to the floor the depth shows.

Why: an amodal box's bottom is the part of it a camera sees least: a table, a chair's neighbours
or the image's lower edge hide it, and the network guesses it from the class's size, while the
top is in view. A few centimetres of height cost a box its overlap with its object as much as a
shift sideways, and the dining chairs behind a table float 20 to 30 cm above the floor where
nothing shows their legs. Beds, chairs, sofas, tables, desks, dressers, night stands, bookshelves,
counters, toilets, bathtubs, garbage bins and doors stand on the floor, and the floor is in the
depth: in the gravity-aligned tilt frame (y down) it is the lowest horizontal layer that holds a
fair share of the frame's points (``floor_plane``, refined to a plane, since an estimated gravity
a degree off tilts a floor seen over 5 m by centimetres). A box of those classes whose bottom
lies within ``REACH_M`` of the floor below its centre keeps its top and reaches down (or up) to
the floor, its footprint and yaw kept; one further off (a chair regressed on a table top, a
frame whose lowest layer is a desk because the floor is out of view) is left as it is. Keeping
the top rather than the height keeps what the 2D box shows inside the 3D box (moving the whole
box down pushed the backs of the dining chairs out of it, and step 5's depth support marked them
down). A frame whose depth holds too few points, or whose lowest layer is no level plane, keeps
every box as regressed and its line says so. Lamps, boxes and sinks often stand on something
else, and pillows, monitors and televisions always do: they keep theirs.

``REACH_M`` was chosen on the 350 a3d-synth frames of seed 2031 that no other number uses
(``python -m bench.depth_steps floor``; docs/real-rooms.md, step 8).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.postprocess.depth_support import SampledDepth
from a3d.runtime.structures.boxes import CENTER, H
from a3d.runtime.structures.classes import class_mask
from a3d.runtime.structures.geometry import evenly_spread

STANDING = frozenset({
    "bathtub", "bed", "bookshelf", "chair", "counter", "desk", "door", "dresser", "garbage bin",
    "night stand", "sofa", "table", "toilet",
})  # fmt: skip
REACH_M = 0.3
MIN_HEIGHT_M = 0.05  # a box whose top the floor would leave lower than this keeps its height
LAYER_M = 0.02  # the height bins the lowest layer is looked for in
LAYER_SHARE = 0.01  # of the frame's points, the least a layer holds to be the floor
MIN_POINTS = 500
MAX_POINTS = 20000  # of the frame's samples (some 75k at 480 x 640): the plane to a millimetre, in 1 ms
MAX_SLOPE = 0.1  # rise per metre of a level floor in the tilt frame (about 6 degrees), at most
NO_FLOOR = "floor: no level floor in the depth, heights as regressed"


def floor_plane(points: np.ndarray, bin_m: float = LAYER_M, share: float = LAYER_SHARE) -> np.ndarray:
    """(a, b, c) of the floor y = a x + b z + c under tilt-frame ``points`` (P, 3), y down. It
    starts as the lowest horizontal layer (largest y) holding ``share`` of the points: the floor,
    however little of it is seen between seats and table tops, which can hold many more. Least
    squares on the points near the plane then refine it, the band narrowing."""
    y = points[:, 1]
    counts, edges = np.histogram(y, bins=np.arange(y.min(), y.max() + bin_m, bin_m))
    low = np.flatnonzero(counts >= share * len(y))[-1]
    plane, band = np.array([0.0, 0.0, (edges[low] + edges[low + 1]) / 2]), 0.15
    for _ in range(6):
        near = points[np.abs(y - points[:, [0, 2]] @ plane[:2] - plane[2]) < band]
        plane = np.linalg.lstsq(np.c_[near[:, [0, 2]], np.ones(len(near))], near[:, 1], rcond=None)[0]
        band = max(0.6 * band, 0.03)
    return plane


def frame_floor(sampled: SampledDepth) -> np.ndarray | None:
    """The floor plane (floor_plane) of a frame's sampled depth (at most ``MAX_POINTS`` of its
    points), or None where it holds fewer than ``MIN_POINTS`` or the plane is steeper than
    ``MAX_SLOPE``."""
    points = sampled.points[sampled.valid]
    if len(points) < MIN_POINTS:
        return None
    plane = floor_plane(evenly_spread(points, MAX_POINTS))
    return plane if np.abs(plane[:2]).max() <= MAX_SLOPE else None


def standing_classes() -> np.ndarray:
    """(19,) bool: the classes whose boxes reach down to the floor."""
    return class_mask(STANDING)


def stand_on_floor(
    boxes3d: np.ndarray, class_idx: np.ndarray, plane: np.ndarray, R_tilt: np.ndarray
) -> np.ndarray:
    """``boxes3d`` (N, 7; camera-frame centre, yaw in the tilt frame of ``R_tilt``) with the
    standing classes' boxes (``class_idx`` 0-based) whose bottom is within ``REACH_M`` of the
    floor ``plane`` (frame_floor) reaching from their top down to it (module docstring)."""
    boxes = np.array(boxes3d, np.float64, copy=True)
    chosen = np.flatnonzero(standing_classes()[np.asarray(class_idx, np.int64)])
    if not len(chosen):
        return boxes
    R = np.asarray(R_tilt, np.float64)
    centres = boxes[chosen][:, CENTER] @ R.T  # tilt frame
    floor = centres[:, 0] * plane[0] + centres[:, 2] * plane[1] + plane[2]
    top = centres[:, 1] - boxes[chosen, H] / 2
    height = floor - top  # the box's height were it to reach the floor; its gap is the difference
    near = (np.abs(height - boxes[chosen, H]) <= REACH_M) & (height >= MIN_HEIGHT_M)
    boxes[chosen[near], H] = height[near]
    centres[near, 1] = top[near] + height[near] / 2
    boxes[chosen[near], CENTER] = centres[near] @ R  # back to the camera frame: p_cam = R^T p_tilt
    return boxes
