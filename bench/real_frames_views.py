"""Pictures of the real frames' 3D boxes, to check each box by eye (bench.real_frames_fit --draw).

A box is judged from more than one side: projected on the colour image it can look right while
standing a metre off in depth. So each picture is three panels: the colour image with the boxes
projected (the hand-drawn 2D boxes dashed and numbered), a top view and a side view of the
frame's depth points in the boxes' tilt frame (gravity down), coloured by height above the floor,
with the boxes' outlines. Per frame all boxes; per object its box alone, zoomed on it, with the
points of its 2D box bright and the others grey, so that what the box was fitted to shows.

With a model's detections (``bench.real_frames_fit --draw DIR --detections FILE``) the frame's
picture also holds the 3D boxes of its detections at or above a score, in their class colours and
labelled with class and score, and the truth's boxes turn grey: whether a detection's box stands
where its object does, and how far off it is in depth, shows in the top and side views.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, CLASSES
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import box_corners_tilt, project_boxes_to_2d
from a3d.runtime.viewer.shapes import projected_box_edges
from bench.contact_sheet import EXPECTED_COLOR, FONT, dashed_rectangle, titled
from bench.real_frames import Boxes3D, HandBoxes

VIEW_SIZE = 480  # pixels high of an object's picture (a frame's is the frame's height)
FRAME_MARGIN_M, OBJECT_MARGIN_M = 0.6, 0.8  # what the views show round the boxes
FLOOR_BAND_M = 0.04  # points this close above the floor are drawn as floor
FLOOR_GREY, OTHER_GREY = 70, 55


@dataclass(frozen=True)
class FrameCloud:
    """A frame's depth as tilt-frame points (H, W, 3), which pixels have depth, and its floor."""

    R_tilt: np.ndarray
    points: np.ndarray
    valid: np.ndarray
    floor: np.ndarray  # (a, b, c): the floor is y = a x + b z + c in the tilt frame

    def floor_y(self, x: np.ndarray | float, z: np.ndarray | float) -> np.ndarray:
        """The floor's height (tilt-frame y, down) under the points (x, z)."""
        return self.floor[0] * np.asarray(x) + self.floor[1] * np.asarray(z) + self.floor[2]


@dataclass(frozen=True)
class Outlines:
    """Boxes to outline in a view: tilt-frame corners (N, 8, 3), BGR colours and labels."""

    corners: np.ndarray
    colours: list[tuple[int, ...]]
    labels: list[str]

    def pick(self, k: int) -> Outlines:
        return Outlines(self.corners[k : k + 1], self.colours[k : k + 1], self.labels[k : k + 1])

    def __add__(self, other: Outlines) -> Outlines:
        corners = np.concatenate([self.corners, other.corners])
        return Outlines(corners, self.colours + other.colours, self.labels + other.labels)


@dataclass(frozen=True)
class Found:
    """A run's detections to draw over the truth: their boxes as the run gives them (camera-frame
    centre, yaw in ``R_tilt``'s frame) and their outlines in the truth's tilt frame."""

    boxes3d: np.ndarray
    R_tilt: np.ndarray
    outlines: Outlines


def found_boxes(found: FrameDetections, threshold: float, R_tilt: np.ndarray) -> Found:
    """``found``'s detections scoring ``threshold`` or more; outlines in the tilt frame of
    ``R_tilt`` (the truth's: the run may have estimated its own), class colours, "class score"."""
    keep = np.flatnonzero(found.scores >= threshold)
    boxes3d, own = found.boxes3d[keep], np.asarray(found.R_tilt, np.float64)
    corners = box_corners_tilt(boxes3d, own) @ own @ np.asarray(R_tilt).T  # own tilt -> camera -> R_tilt's
    ids = found.class_ids[keep]
    labels = [f"{CLASSES[c]} {s:.2f}" for c, s in zip(ids, found.scores[keep], strict=True)]
    return Found(boxes3d, own, Outlines(corners, [CLASS_COLORS_RGB[c][::-1] for c in ids], labels))


def draw_frame(
    frame: Frame, cloud: FrameCloud, hand: HandBoxes, boxes: Boxes3D, found: Found | None = None
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The frame's picture, and one picture per boxed object (module docstring); ``cloud`` is the
    frame's depth in the boxes' tilt frame; ``found``: detections' boxes (``found_boxes``) drawn
    over the truth's, which then are grey."""
    truth = boxes.truth
    colours = [CLASS_COLORS_RGB[c][::-1] for c in truth.class_ids]
    outlines = Outlines(
        box_corners_tilt(truth.boxes3d, truth.R_tilt), colours, [str(i) for i in boxes.objects]
    )
    points = cloud.points[cloud.valid]
    skipped = sorted(set(range(len(hand.boxes))) - set(boxes.objects.tolist()))
    title = f"{frame.name}: {len(boxes.objects)} of {len(hand.boxes)} boxed" + (
        f", skipped {', '.join(map(str, skipped))}" if skipped else ""
    )
    shown = outlines
    if found is None:
        image = _on_image(frame, hand, boxes, colours, range(len(boxes.objects)))
    else:
        grey = [EXPECTED_COLOR] * len(colours)
        shown = Outlines(outlines.corners, grey, outlines.labels) + found.outlines
        image = _on_image(frame, hand, boxes, grey, range(len(boxes.objects)), found)
        title += f"; {len(found.boxes3d)} detections (colour), the truth grey"
    views = _views(cloud, points, _tints(cloud, points), shown, FRAME_MARGIN_M, image.shape[0])
    scene = titled(np.hstack([image, *views]), title)
    pixel_ids = np.flatnonzero(cloud.valid)
    zoomed = []
    for k, i in enumerate(boxes.objects):
        crop = _crop(_on_image(frame, hand, boxes, colours, [k]), hand.boxes[i], frame, boxes, k)
        bright = _tints(cloud, points, np.isin(pixel_ids, _pixel_ids(hand.boxes[i], cloud.valid.shape[1])))
        views = _views(cloud, points, bright, outlines.pick(k), OBJECT_MARGIN_M, VIEW_SIZE)
        box = np.round(truth.boxes3d[k], 2).tolist()
        zoomed.append(
            titled(np.hstack([crop, *views]), f"{frame.name} object {i}: {CLASSES[truth.class_ids[k]]} {box}")
        )
    return scene, zoomed


def _on_image(
    frame: Frame,
    hand: HandBoxes,
    boxes: Boxes3D,
    colours: list,
    which: Iterable[int],
    found: Found | None = None,
) -> np.ndarray:
    """The colour image with the hand-drawn boxes dashed and numbered, the 3D boxes ``which``
    (indices into ``boxes``) projected in ``colours``, and ``found``'s boxes over them."""
    image = frame.color.copy()
    for i, box2d in enumerate(hand.boxes):
        dashed_rectangle(image, box2d, EXPECTED_COLOR)
        _label(image, str(i), (round(box2d[0]) + 3, round(box2d[1]) + 16), EXPECTED_COLOR)
    truth = boxes.truth
    for k in which:
        edges = projected_box_edges(truth.boxes3d[k : k + 1], truth.R_tilt, frame.intrinsics, image.shape[:2])
        _lines(image, edges, colours[k])
    if found is not None:
        labels = found.outlines
        for box, colour, label in zip(found.boxes3d, labels.colours, labels.labels, strict=True):
            edges = projected_box_edges(box[None], found.R_tilt, frame.intrinsics, image.shape[:2])
            _lines(image, edges, colour)
            ends = edges[np.isfinite(edges).all(axis=(1, 2))].reshape(-1, 2)
            if len(ends):
                u, v = np.maximum(ends.min(axis=0), 0)
                _label(image, label, (int(u) + 3, int(v) + 16), colour)
    return image


def _lines(image: np.ndarray, edges: np.ndarray, colour: tuple[int, ...]) -> None:
    """Draw the finite ones of projected edges (E, 2, 2) in ``colour``."""
    for a, b in np.round(edges[np.isfinite(edges).all(axis=(1, 2))]).astype(int):
        cv2.line(image, tuple(a), tuple(b), colour, 2, cv2.LINE_AA)


def _crop(image: np.ndarray, box2d: np.ndarray, frame: Frame, boxes: Boxes3D, k: int) -> np.ndarray:
    """The part of ``image`` round an object's 2D box and its projected 3D box, VIEW_SIZE high."""
    truth = boxes.truth
    amodal = project_boxes_to_2d(truth.boxes3d[k : k + 1], truth.R_tilt, frame.intrinsics, image.shape[:2])[0]
    (x1, y1), (x2, y2) = np.minimum(box2d[:2], amodal[:2]), np.maximum(box2d[2:], amodal[2:])
    grow = 0.1 * max(x2 - x1, y2 - y1)
    crop = image[max(0, int(y1 - grow)) : int(y2 + grow) + 1, max(0, int(x1 - grow)) : int(x2 + grow) + 1]
    return cv2.resize(crop, (round(crop.shape[1] * VIEW_SIZE / crop.shape[0]), VIEW_SIZE))


def _pixel_ids(box2d: np.ndarray, width: int) -> np.ndarray:
    """Flat indices of the pixels inside a 2D box."""
    x1, y1, x2, y2 = box2d
    rows, cols = np.mgrid[int(np.ceil(y1)) : int(np.floor(y2)) + 1, int(np.ceil(x1)) : int(np.floor(x2)) + 1]
    return (rows * width + cols).ravel()


def _tints(cloud: FrameCloud, points: np.ndarray, bright: np.ndarray | None = None) -> np.ndarray:
    """BGR colours of points by height above the floor (up to 2 m), the floor grey; with ``bright``
    (a mask) only those points so, the others dark grey."""
    height = cloud.floor_y(points[:, 0], points[:, 2]) - points[:, 1]
    scaled = np.round(255 * np.clip(height / 2.0, 0, 1)).astype(np.uint8)
    tints = cv2.applyColorMap(scaled[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]
    tints[height < FLOOR_BAND_M] = FLOOR_GREY
    if bright is not None:
        tints[~bright] = OTHER_GREY
    return tints


def _views(
    cloud: FrameCloud, points: np.ndarray, tints: np.ndarray, outlines: Outlines, margin: float, size: int
) -> list[np.ndarray]:
    """The top view (x right, z up the picture) and the side view (z right, y down, only the points
    beside the boxes) of the points and outlines, ``size`` pixels square, ``margin`` metres round
    the boxes."""
    region = outlines.corners.reshape(-1, 3)
    if not len(region):  # a frame without boxes: the bulk of its points
        region = np.percentile(points, [2, 98], axis=0)
    x = region[:, 0]
    beside = (points[:, 0] > x.min() - margin / 2) & (points[:, 0] < x.max() + margin / 2)
    floor = float(cloud.floor_y(x.mean(), region[:, 2].mean()))
    return [
        _view(points, tints, outlines, region, (0, 2), margin, size, np.ones(len(points), bool), None),
        _view(points, tints, outlines, region, (2, 1), margin, size, beside, floor),
    ]


def top_view(cloud: FrameCloud, points: np.ndarray, outlines: Outlines, size: int) -> np.ndarray:
    """The top view of ``points`` (tilt frame, coloured by height above the floor) and ``outlines``,
    ``size`` pixels square."""
    return _views(cloud, points, _tints(cloud, points), outlines, FRAME_MARGIN_M, size)[0]


def _view(
    points: np.ndarray,
    tints: np.ndarray,
    outlines: Outlines,
    region: np.ndarray,
    axes: tuple[int, int],
    margin: float,
    size: int,
    keep: np.ndarray,
    floor: float | None,
) -> np.ndarray:
    """One view along tilt-frame ``axes`` (across the picture, down it) of ``region`` (points) and
    ``margin`` round it; ``floor``: a side view, kept in sight, else the top view, its second axis
    (z) flipped to grow upwards."""
    top = floor is None
    corners = outlines.corners[..., list(axes)]
    low, high = region[:, axes].min(axis=0) - margin, region[:, axes].max(axis=0) + margin
    if not top:
        high[1] = max(high[1], floor + 0.1)
    scale = (size - 1) / (high - low).max()

    def pixels(xy: np.ndarray) -> np.ndarray:
        uv = (xy - low) * scale
        if top:
            uv[..., 1] = size - 1 - uv[..., 1]
        return np.round(uv).astype(np.int32)

    uv = pixels(points[:, list(axes)])
    keep = keep & ((uv >= 0) & (uv < size)).all(axis=1)
    order = np.flatnonzero(keep)[np.argsort(tints[keep].sum(axis=1), kind="stable")]  # bright points on top
    view = np.full((size, size, 3), 16, np.uint8)
    view[uv[order, 1], uv[order, 0]] = tints[order]
    for box, colour, label in zip(corners, outlines.colours, outlines.labels, strict=True):
        shape = pixels(box[:4]) if top else cv2.convexHull(pixels(box))  # footprint; side silhouette
        cv2.polylines(view, [shape.reshape(-1, 1, 2)], True, colour, 2, cv2.LINE_AA)
        u, v = shape.reshape(-1, 2).min(axis=0)
        _label(view, label, (int(u) + 3, int(v) + 16), colour)
    cv2.putText(view, "top" if top else "side", (6, 20), FONT, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return view


def _label(image: np.ndarray, text: str, corner: tuple[int, int], colour: tuple[int, ...]) -> None:
    """``text`` in ``colour`` with a black rim, readable on the image and on the dark views."""
    cv2.putText(image, text, corner, FONT, 0.55, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, corner, FONT, 0.55, colour, 1, cv2.LINE_AA)
