"""The room's wall directions from a frame's depth, and 3D boxes turned square to them.

Why: rooms are built square and most furniture stands square to their walls (doors in them;
beds, dressers, counters, bookshelves and sofas against them), but a yaw regressed from one RoI
is often tens of degrees off, and for a thin object that is the whole box: a door turned by 30
degrees crosses the wall and overlaps its own box by next to nothing. The walls are in the depth:
the normals of a frame's vertical surfaces (walls, cabinet fronts, doors) bunch about one
direction modulo 90 degrees in the gravity-aligned tilt frame. Where at least ``MIN_SHARE`` of
them lie within ``BUNCH_DEG`` of it, a box whose yaw is within ``SNAP_DEG`` of a wall direction is
turned onto it; a box further off (a chair turned to a table's corner) keeps its yaw, as do all
where the depth shows no walls (the frame's line says so).

Directions are in the boxes' yaw convention (docs/conventions.md "3D boxes"): a yaw ``theta``
has its length axis along ``(cos theta, -sin theta)`` in the tilt frame's (x, z).
"""

from __future__ import annotations

import numpy as np

from a3d.runtime.frontend.normals import normal_grid
from a3d.runtime.structures.boxes import THETA
from a3d.runtime.structures.geometry import CameraLike, canonical_boxes

SNAP_DEG = 20.0
BUNCH_DEG = 5.0
MIN_SHARE = 0.1
MIN_NORMALS = 50
VERTICAL = 0.2  # |gravity component| of a vertical surface's unit normal, at most
QUARTER = np.pi / 2
NO_WALLS = "walls: no wall direction in the depth, yaws as regressed"


def wall_direction(depth: np.ndarray, K: CameraLike, R_tilt: np.ndarray) -> float | None:
    """The frame's wall direction (radians in [-pi/4, pi/4), modulo a quarter turn), or None where
    fewer than ``MIN_NORMALS`` vertical normals or under ``MIN_SHARE`` of them bunch about one."""
    grid = normal_grid(np.asarray(depth, np.float32), K)
    normals = grid.normals[grid.valid].astype(np.float64) @ np.asarray(R_tilt, np.float64).T
    vertical = normals[np.abs(normals[:, 1]) < VERTICAL]
    if len(vertical) < MIN_NORMALS:
        return None
    turns = 4.0 * np.arctan2(-vertical[:, 2], vertical[:, 0])  # a quarter turn = a full circle
    bins = np.round(np.degrees(turns) / 4.0).astype(np.int64) % 90  # one per degree of direction
    counts = np.bincount(bins, minlength=90)
    reach = int(BUNCH_DEG)
    bunched = sum(np.roll(counts, k) for k in range(-reach, reach + 1))
    peak = 4.0 * np.radians(float(np.argmax(bunched)))
    near = np.abs(np.angle(np.exp(1j * (turns - peak)))) <= 4.0 * np.radians(BUNCH_DEG)
    if near.mean() < MIN_SHARE:
        return None
    mean = float(np.angle(np.exp(1j * turns[near]).mean())) / 4.0
    return (mean + np.pi / 4) % QUARTER - np.pi / 4


def square_to_walls(boxes3d: np.ndarray, direction: float) -> np.ndarray:
    """``boxes3d`` (N, 7) with each yaw within ``SNAP_DEG`` of a wall ``direction`` (wall_direction)
    turned onto it; the others as they are."""
    boxes = np.array(boxes3d, np.float64, copy=True)
    off = (boxes[:, THETA] - direction + np.pi / 4) % QUARTER - np.pi / 4
    near = np.abs(off) <= np.radians(SNAP_DEG)
    boxes[near, THETA] -= off[near]
    return canonical_boxes(boxes) if len(boxes) else boxes
