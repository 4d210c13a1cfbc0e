"""Fit a gravity-aligned box to the points a user's rough box encloses: labels drawn once, made exact.

Why: labelling a recording (a3d-labels) needs each object's box once, in a gravity-aligned world
(y down). Typing one to the centimetre is hard; a rough box around the object is easy. This
module fuses a posed recording's depth into world points and fits, to the points inside a rough
box (grown by a margin), the box a3d uses: the smallest-area rectangle of their footprint (OpenCV's
``minAreaRect``), their height range, in the 7-vector convention (l >= w, yaw in [-pi/2, pi/2]).
docs/mapping.md "Drawing the world boxes" gives the procedure.
"""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.mapping.labels import LabelConfig, inside_box
from a3d.runtime.structures.boxes import L, W
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import backproject, boxes_from_corners_tilt
from a3d.runtime.structures.pose import transform_points

MIN_POINTS = 20  # fewer points inside a rough box are no object's surface
FLOOR_SEARCH_M = 0.3  # the floor is looked for this far above the cloud's lowest points
FLOOR_GAP_M = 0.03  # points this close to the floor are the floor's, not an object's
FLOOR_SNAP_M = 0.1  # a fitted box whose bottom is this close to the floor stands on it
CELL_M = 0.02  # footprint cells in which an object's points are told from a neighbour's


def world_points(frames: Iterable[Frame], stride: int = 4) -> np.ndarray:
    """(N, 3) world points of posed frames' depth (every ``stride``-th pixel each way; frames without
    a pose are left out): the point cloud to fit boxes to."""
    return world_cloud(frames, stride)[0]


def world_cloud(frames: Iterable[Frame], stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """``world_points`` and their colours (N, 3) uint8 RGB: the cloud a person draws rough boxes in."""
    clouds, colours = [], []
    for frame in frames:
        if frame.pose is None:
            continue
        rows, cols = (index[::stride, ::stride] for index in np.indices(frame.depth.shape, dtype=np.float64))
        depth = frame.depth[::stride, ::stride]
        seen = depth > 0  # only the sampled, measured pixels are back-projected
        points = backproject(cols[seen], rows[seen], depth[seen].astype(np.float64), frame.intrinsics)
        clouds.append(transform_points(frame.pose, points))
        colours.append(frame.color[::stride, ::stride][seen][:, ::-1])  # BGR -> RGB
    if not clouds:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    return np.concatenate(clouds), np.concatenate(colours)


def floor_level(points: np.ndarray) -> float | None:
    """The floor's y (the fullest centimetre of y among the lowest 30 cm of the cloud; y is down), or
    None for too few points: what standing objects' boxes reach down to."""
    ys = np.asarray(points, np.float64)[:, 1]
    if len(ys) < MIN_POINTS:
        return None
    lowest = float(np.percentile(ys, 99.5))  # a few noisy points below the floor do not count
    counts, edges = np.histogram(ys, bins=np.arange(lowest - FLOOR_SEARCH_M, lowest + 0.05, 0.01))
    k = int(np.argmax(counts))
    return float(0.5 * (edges[k] + edges[k + 1]))


def _connected_to_core(points: np.ndarray, rough: np.ndarray) -> np.ndarray:
    """Which points lie in footprint cells (``CELL_M``, closed by one cell) connected to the rough
    box's core (the middle half of its footprint, or where it holds no point, the component with
    most points inside the rough box): with the floor gone, a wall or a neighbour the margin
    reaches into stands apart from the object, unless it touches it."""
    if not len(points):
        return np.zeros(0, bool)
    cells = np.floor(points[:, [0, 2]] / CELL_M).astype(np.int64)
    cells -= cells.min(axis=0)
    grid = np.zeros(tuple(cells.max(axis=0) + 1), np.uint8)
    grid[cells[:, 0], cells[:, 1]] = 1
    grid = cv2.dilate(grid, np.ones((3, 3), np.uint8))  # a gap of one cell is no gap
    labels = cv2.connectedComponents(grid, connectivity=8)[1][cells[:, 0], cells[:, 1]]
    core, tight = rough.copy(), LabelConfig(margin_m=0.0, floor_gap_m=0.0)
    core[[L, W]] /= 2
    touching = labels[inside_box(points, core, np.eye(3), tight)]
    if not len(touching):  # a part seen from one side: the fullest component inside the rough box
        within = labels[inside_box(points, rough, np.eye(3), tight)]
        touching = [np.bincount(within if len(within) else labels).argmax()]
    return np.isin(labels, touching)


def fit_box(
    points: np.ndarray, rough: np.ndarray, margin_m: float = 0.1, floor_y: float | None = None
) -> np.ndarray:
    """The gravity-aligned box (world 7-vector) of the world ``points`` inside ``rough`` grown by
    ``margin_m``: footprint by the smallest-area rectangle, height by the points' y range.

    With ``floor_y`` (``floor_level``), points within ``FLOOR_GAP_M`` of the floor are left out
    (the floor round an object's foot would widen its footprint), and a box whose bottom ends within
    ``FLOOR_SNAP_M`` of the floor is extended down to it (the object stands there)."""
    config = LabelConfig(margin_m=margin_m, floor_gap_m=0.0)
    points = np.asarray(points, np.float64)
    inside = points[inside_box(points, np.asarray(rough, np.float64), np.eye(3), config)]
    if floor_y is not None:
        inside = inside[inside[:, 1] < floor_y - FLOOR_GAP_M]
        connected = _connected_to_core(inside, np.asarray(rough, np.float64))
        inside = inside[connected] if connected.sum() >= MIN_POINTS else inside  # else too sparse to tell
    if len(inside) < MIN_POINTS:
        raise InputError(f"rough box {np.round(rough, 3).tolist()}: {len(inside)} points inside, "
                         f"need {MIN_POINTS} (is it where the object is?)")  # fmt: skip
    footprint = cv2.boxPoints(cv2.minAreaRect(inside[:, [0, 2]].astype(np.float32))).astype(np.float64)
    top, bottom = inside[:, 1].min(), inside[:, 1].max()  # y is down: the lower face has the larger y
    if floor_y is not None and floor_y - bottom < FLOOR_SNAP_M:
        bottom = max(bottom, floor_y)
    corners = np.zeros((1, 8, 3))
    corners[0, :4, [0, 2]] = footprint.T
    corners[0, 4:, [0, 2]] = footprint.T
    corners[0, :4, 1], corners[0, 4:, 1] = bottom, top
    return boxes_from_corners_tilt(corners, np.eye(3))[0]
