"""Fit a gravity-aligned box to the points a user's rough box encloses: labels drawn once, made exact.

Why: labelling a recording (a3d-labels) needs each object's box once, in a gravity-aligned world
(y down). Typing one to the centimetre is hard; a rough box around the object is easy. This
module fuses a posed recording's depth into world points and fits, to the points inside a rough
box (grown by a margin), the box a3d uses: its footprint turned, in whole degrees, to the smallest
rectangle round theirs, each face where the points end, in the 7-vector convention
(l >= w, yaw in [-pi/2, pi/2]). Two things make the points end elsewhere than the object: the
sensor's noise, a few stray centimetres beyond every surface (the outermost ``TRIM_PERCENT`` of
the points along each axis are left out), and what the object touches (a wall, a counter, a
neighbour), whose points run on to the edge of the search region: a face that ends there was cut
by it, not by the object, and the rough box's own face is the better guess. And where no frame saw
a part of the object (a door's top above every view, a basin's bottom, a counter's back behind
its top), the points end short of it: a face far inside the rough box's is kept only where some
frame saw through the space it would give up (the recording's depth says so), else the rough
box's face stands. Points that span under half the rough box's width are a part of the object (a
chair's back seen from behind): the rough box's sides across them stand.
docs/mapping.md "Drawing the world boxes" gives the procedure.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.mapping.labels import LabelConfig, inside_box
from a3d.runtime.structures.boxes import L, W
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import (
    CameraLike,
    backproject,
    box_corners_tilt,
    boxes_from_corners_tilt,
    depth_seen_at,
    evenly_spread,
    points_in_box,
)
from a3d.runtime.structures.pose import invert_pose, transform_points

MIN_POINTS = 20  # fewer points inside a rough box are no object's surface
FLOOR_SEARCH_M = 0.3  # the floor is looked for this far above the cloud's lowest points
FLOOR_GAP_M = 0.03  # points this close to the floor are the floor's, not an object's
FLOOR_SNAP_M = 0.1  # a fitted box whose bottom is this close to the floor stands on it
CELL_M = 0.02  # footprint cells in which an object's points are told from a neighbour's
TRIM_PERCENT = 1.0  # of the points along each axis, left out at either end: the sensor's stray depth
EDGE_M = 0.02  # a face whose outermost points lie this close to the search region's edge was cut there
YAW_SAMPLE = 4000  # footprint points the turn is chosen on
SHRINK_M = 0.10  # a face this far inside the rough box's is checked against what the camera saw
FREE_M = 0.05  # a point the camera saw this far beyond, in some frame, is free space
NEAR_M = 0.1  # points nearer a camera than this are not looked at in its view
FREE_SHARE = 0.5  # a face moves in only where this share of the space it gives up was seen free
SLAB_SAMPLES = 5  # per side of the space a face gives up, and 3 deep
MIN_SPAN_SHARE = 0.5  # points spanning less of the rough box's width (and 10 cm less) are a part


@dataclass(frozen=True)
class DepthView:
    """A posed frame's depth, every ``stride``-th pixel: what says which space the camera saw through."""

    depth: np.ndarray  # (h, w) metres, 0 where missing
    K: CameraLike  # the full frame's
    stride: int
    world_to_camera: np.ndarray  # (4, 4)


@dataclass(frozen=True)
class WorldCloud:
    """A posed recording's world points, their colours (RGB) and its frames' depth views."""

    points: np.ndarray
    colours: np.ndarray
    views: list[DepthView]


@dataclass(frozen=True)
class Fitted:
    """A fitted box (world 7-vector), its faces that stayed the rough box's because no frame saw
    past where the points end ("side", "top", "bottom"), and the pairs of sides that stayed the
    rough box's because the points span less than half the way between them (``part_seen``): what
    the person should look at."""

    box: np.ndarray
    unseen: tuple[str, ...] = ()
    part_seen: int = 0


def world_points(frames: Iterable[Frame], stride: int = 4) -> np.ndarray:
    """(N, 3) world points of posed frames' depth (every ``stride``-th pixel each way; frames without
    a pose are left out): the point cloud to fit boxes to."""
    return world_cloud(frames, stride).points


def world_cloud(frames: Iterable[Frame], stride: int = 4) -> WorldCloud:
    """``world_points``, their colours (N, 3) uint8 RGB and each posed frame's depth view: the cloud
    a person draws rough boxes in, and what the camera saw through."""
    clouds, colours, views = [], [], []
    for frame in frames:
        if frame.pose is None:
            continue
        rows, cols = (index[::stride, ::stride] for index in np.indices(frame.depth.shape, dtype=np.float64))
        depth = frame.depth[::stride, ::stride]
        seen = depth > 0  # only the sampled, measured pixels are back-projected
        points = backproject(cols[seen], rows[seen], depth[seen].astype(np.float64), frame.intrinsics)
        clouds.append(transform_points(frame.pose, points))
        colours.append(frame.color[::stride, ::stride][seen][:, ::-1])  # BGR -> RGB
        views.append(DepthView(depth.astype(np.float32), frame.intrinsics, stride, invert_pose(frame.pose)))
    if not clouds:
        return WorldCloud(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), [])
    return WorldCloud(np.concatenate(clouds), np.concatenate(colours), views)


def seen_free(points: np.ndarray, views: list[DepthView]) -> np.ndarray:
    """(N,) bool: world ``points`` that some view saw through (its depth there more than ``FREE_M``
    beyond them): free space, not an object's."""
    free = np.zeros(len(points), bool)
    for view in views:
        camera = transform_points(view.world_to_camera, points)
        observed = depth_seen_at(camera, view.depth, view.K, view.stride, NEAR_M)
        free |= (observed > 0) & (observed > camera[:, 2] + FREE_M)  # 0: not seen (behind it, too)
    return free


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
    """``fitted_box``'s box without the recording's views: the faces where the points end."""
    return fitted_box(points, rough, margin_m, floor_y).box


def fitted_box(
    points: np.ndarray,
    rough: np.ndarray,
    margin_m: float = 0.1,
    floor_y: float | None = None,
    views: list[DepthView] | None = None,
) -> Fitted:
    """The gravity-aligned box (world 7-vector) of the world ``points`` inside ``rough`` grown by
    ``margin_m`` (module docstring): footprint turned to their smallest rectangle, each side
    and the top where the points end (``TRIM_PERCENT``), or the rough box's own where they run on
    to the edge of the search region (``EDGE_M``).

    With ``floor_y`` (``floor_level``), points within ``FLOOR_GAP_M`` of the floor are left out
    (the floor round an object's foot would widen its footprint), and a box whose bottom ends within
    ``FLOOR_SNAP_M`` of the floor is extended down to it (the object stands there). With the
    recording's depth ``views`` (``world_cloud``), a face more than ``SHRINK_M`` inside the rough
    box's stays where the points end only if some frame saw through the space it gives up, else it
    is the rough box's (``_unseen_kept``). Where the points span less than ``MIN_SPAN_SHARE`` of
    the rough box's width or length (and ``SHRINK_M`` less), they are a part of the object (a
    chair's back seen from behind, the views seeing through between its legs: free space that
    is the object's all the same) and the rough box's two sides stand."""
    config = LabelConfig(margin_m=margin_m, floor_gap_m=0.0)
    points, rough = np.asarray(points, np.float64), np.asarray(rough, np.float64)
    inside = points[inside_box(points, rough, np.eye(3), config)]
    if floor_y is not None:
        inside = inside[inside[:, 1] < floor_y - FLOOR_GAP_M]
        connected = _connected_to_core(inside, rough)
        inside = inside[connected] if connected.sum() >= MIN_POINTS else inside  # else too sparse to tell
    if len(inside) < MIN_POINTS:
        raise InputError(f"rough box {np.round(rough, 3).tolist()}: {len(inside)} points inside, "
                         f"need {MIN_POINTS} (is it where the object is?)")  # fmt: skip
    side_edge, top_edge = _at_search_edge(inside, rough, margin_m)
    axes = _footprint_axes(inside[:, [0, 2]])
    rough_footprint = box_corners_tilt(rough[None], np.eye(3))[0, :4][:, [0, 2]]
    bounds = np.zeros((2, 2))
    for k, axis in enumerate(axes):
        rough_along = rough_footprint @ axis
        bounds[k] = _faces(inside[:, [0, 2]] @ axis, side_edge, rough_along.min(), rough_along.max())
    heights = inside[:, 1]  # y is down: the top is the smallest
    top = _faces(heights, top_edge, rough[1] - rough[5] / 2, np.inf)[0]
    bottom = heights.max()
    if floor_y is not None and floor_y - bottom < FLOOR_SNAP_M:
        bottom = max(bottom, floor_y)
    unseen: tuple[str, ...] = ()
    rough_top, rough_bottom = rough[1] - rough[5] / 2, rough[1] + rough[5] / 2
    rough_bottom = rough_bottom if floor_y is None else min(rough_bottom, floor_y)
    rough_faces = np.vstack([_rough_along(rough_footprint, axes), [rough_top, rough_bottom]])
    if views:
        faces, unseen = _unseen_kept(np.vstack([bounds, [top, bottom]]), rough_faces, axes, views)
        bounds, (top, bottom) = faces[:2], faces[2]
    spans, rough_spans = np.diff(bounds, axis=1)[:, 0], np.diff(rough_faces[:2], axis=1)[:, 0]
    part_seen = (spans < MIN_SPAN_SHARE * rough_spans) & (rough_spans - spans > SHRINK_M)
    bounds[part_seen] = rough_faces[:2][part_seen]
    (u0, u1), (v0, v1) = bounds
    footprint = np.array([u0 * axes[0] + v0 * axes[1], u1 * axes[0] + v0 * axes[1],
                          u1 * axes[0] + v1 * axes[1], u0 * axes[0] + v1 * axes[1]])  # fmt: skip
    corners = np.zeros((1, 8, 3))
    corners[0, :4, [0, 2]] = footprint.T
    corners[0, 4:, [0, 2]] = footprint.T
    corners[0, :4, 1], corners[0, 4:, 1] = bottom, top
    return Fitted(boxes_from_corners_tilt(corners, np.eye(3))[0], unseen, int(part_seen.sum()))


def _rough_along(footprint: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(2, 2) the rough box's low and high faces along the fit's footprint ``axes``: its centre's
    place along each, less and plus half its own side nearest that axis (the corners' extent along a
    turned axis would widen a thin box by its length's share)."""
    sides = np.stack([footprint[1] - footprint[0], footprint[3] - footprint[0]])  # (2, (x, z))
    lengths = np.linalg.norm(sides, axis=1)
    centre = footprint.mean(axis=0)
    out = np.zeros((2, 2))
    for k, axis in enumerate(axes):
        half = lengths[np.argmax(np.abs(sides @ axis) / lengths)] / 2
        out[k] = centre @ axis - half, centre @ axis + half
    return out


def _unseen_kept(
    faces: np.ndarray, rough_faces: np.ndarray, axes: np.ndarray, views: list[DepthView]
) -> tuple[np.ndarray, tuple[str, ...]]:
    """``faces`` (3, 2: low and high along the two footprint ``axes``, then top and bottom, y down)
    with each that lies more than ``SHRINK_M`` inside the rough box's (``rough_faces``) put back at
    the rough box's, unless some frame saw through most of the space it gives up (``seen_free``):
    where the points end only because no frame saw further, the rough box is the better guess.
    Also the names of the faces put back."""
    faces = np.array(faces, np.float64)
    names = (("side", "side"), ("side", "side"), ("top", "bottom"))
    unseen = []
    for k in range(3):
        for side, inward in ((0, 1.0), (1, -1.0)):
            fitted, rough = faces[k, side], rough_faces[k, side]
            if inward * (fitted - rough) > SHRINK_M:
                spans = faces.copy()
                spans[k] = fitted, rough
                if seen_free(_slab_samples(spans, k, axes), views).mean() < FREE_SHARE:
                    faces[k, side] = rough
                    unseen.append(names[k][side])
    return faces, tuple(unseen)


def _slab_samples(spans: np.ndarray, k: int, axes: np.ndarray) -> np.ndarray:
    """World points spread through the box of ``spans`` (3, 2; as ``_unseen_kept``'s faces): a grid
    of ``SLAB_SAMPLES`` a side, 3 deep along span ``k``."""
    grid = (np.arange(SLAB_SAMPLES) + 0.5) / SLAB_SAMPLES
    fractions = [np.array([1 / 6, 1 / 2, 5 / 6]) if i == k else grid for i in range(3)]
    values = [low + (high - low) * f for (low, high), f in zip(spans, fractions, strict=True)]
    u, v, y = (g.ravel() for g in np.meshgrid(*values, indexing="ij"))
    xz = u[:, None] * axes[0] + v[:, None] * axes[1]
    return np.column_stack([xz[:, 0], y, xz[:, 1]])


def _footprint_axes(footprint: np.ndarray) -> np.ndarray:
    """(2, 2) the directions in (x, z) of the footprint's sides: the turn, in whole degrees, whose
    rectangle of the trimmed extents (``TRIM_PERCENT``) is the smallest (a rectangle round every
    point, OpenCV's ``minAreaRect``, turns with the strays)."""
    sample = evenly_spread(footprint, YAW_SAMPLE)
    turns = np.radians(np.arange(90))
    cos, sin = np.cos(turns), np.sin(turns)
    axes = np.stack([np.stack([cos, sin], 1), np.stack([-sin, cos], 1)], 1)  # (turn, axis, (x, z))
    along = np.einsum("pc,tac->tap", sample, axes)  # (turn, axis, point)
    low, high = np.percentile(along, [TRIM_PERCENT, 100 - TRIM_PERCENT], axis=2)
    return axes[int(np.argmin(np.prod(high - low, axis=1)))]


def _at_search_edge(inside: np.ndarray, rough: np.ndarray, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Which points lie within ``EDGE_M`` of the search region's sides, and of its top (the rough
    box grown by ``margin_m``): where a neighbour or a wall the margin reaches into runs on."""
    shrunk = max(margin_m - EDGE_M, 0.0)
    top = inside[:, 1] < rough[1] - rough[5] / 2 - shrunk  # y is down
    sides = ~points_in_box(inside, rough, np.eye(3), shrunk, 0.0) & ~top
    return sides, top


def _faces(along: np.ndarray, at_edge: np.ndarray, rough_low: float, rough_high: float) -> np.ndarray:
    """The low and high faces of points' coordinates ``along`` one axis: their trimmed ends
    (``TRIM_PERCENT``), or the rough box's where most points within ``EDGE_M`` of the end (and
    beyond it) lie at the search region's edge (``at_edge``): something runs on there."""
    low, high = np.percentile(along, [TRIM_PERCENT, 100 - TRIM_PERCENT])
    low = rough_low if at_edge[along <= low + EDGE_M].mean() > 0.5 else low
    high = rough_high if at_edge[along >= high - EDGE_M].mean() > 0.5 else high
    return np.array([low, high])
