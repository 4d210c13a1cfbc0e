"""A contact sheet of frames with 2D boxes drawn on them (OpenCV only), for bench.real_frames.

A sheet lets a reader judge a model on frames nobody annotated in 3D at a glance: each frame is a
tile with the model's boxes drawn as a result draws itself (a3d.runtime.viewer.draw: the viewer's
class colours, "class score" labels), and the expected objects as thin dashed grey boxes.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from a3d.runtime.viewer.draw import draw_detections

FONT = cv2.FONT_HERSHEY_SIMPLEX
TITLE_HEIGHT = 30
GAP = 6
BACKGROUND = (32, 32, 32)
EXPECTED_COLOR = (215, 215, 215)  # BGR light grey: the hand-drawn boxes, apart from every class colour


@dataclass(frozen=True)
class TileBoxes:
    """What one tile shows: the model's boxes (class index, score, box) and the expected boxes."""

    class_ids: np.ndarray  # (N,) 0-based CLASSES index
    scores: np.ndarray  # (N,)
    boxes: np.ndarray  # (N, 4) [x1, y1, x2, y2] pixels
    expected: np.ndarray  # (M, 4) hand-drawn boxes, drawn dashed


def dashed_rectangle(image: np.ndarray, box: np.ndarray, color: tuple[int, int, int], dash: int = 7) -> None:
    """A 1-pixel dashed box: OpenCV has none, and a solid one would read as a detection."""
    x1, y1, x2, y2 = (round(float(v)) for v in box)
    corners = [(x1, y1), (x2, y1), (x2, y2), (x1, y2), (x1, y1)]
    for (ax, ay), (bx, by) in itertools.pairwise(corners):
        length = max(abs(bx - ax), abs(by - ay), 1)
        for start in range(0, length, 2 * dash):
            t0, t1 = start / length, min(start + dash, length) / length
            p = (round(ax + (bx - ax) * t0), round(ay + (by - ay) * t0))
            q = (round(ax + (bx - ax) * t1), round(ay + (by - ay) * t1))
            cv2.line(image, p, q, color, 1, cv2.LINE_AA)


def draw_tile(color_bgr: np.ndarray, title: str, shown: TileBoxes) -> np.ndarray:
    """One frame as a tile: a title bar over the image with the expected boxes dashed and the
    model's boxes solid; the highest score is drawn last so its label stays on top."""
    image = color_bgr.copy()
    for box in shown.expected:
        dashed_rectangle(image, box, EXPECTED_COLOR)
    order = np.argsort(shown.scores, kind="stable")  # the result's own drawing, in the viewer's colours
    image = draw_detections(image, shown.class_ids[order], shown.scores[order], shown.boxes[order], bgr=True)
    return titled(image, title)


def titled(image: np.ndarray, title: str) -> np.ndarray:
    """``image`` under a title bar, as every tile of a sheet is."""
    bar = np.full((TITLE_HEIGHT, image.shape[1], 3), BACKGROUND, np.uint8)
    cv2.putText(bar, title, (6, TITLE_HEIGHT - 9), FONT, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([bar, image])


def contact_sheet(tiles: Sequence[np.ndarray], columns: int = 3, header: str = "") -> np.ndarray:
    """Tiles in rows of ``columns`` (each cell the size of the largest tile), under a header line."""
    if not tiles:
        raise ValueError("contact_sheet: no tiles")
    cell_h = max(t.shape[0] for t in tiles)
    cell_w = max(t.shape[1] for t in tiles)
    columns = max(1, min(columns, len(tiles)))
    rows = -(-len(tiles) // columns)
    top = TITLE_HEIGHT if header else 0
    sheet = np.full(
        (top + rows * cell_h + (rows + 1) * GAP, columns * cell_w + (columns + 1) * GAP, 3),
        BACKGROUND,
        np.uint8,
    )
    if header:
        cv2.putText(sheet, header, (GAP, TITLE_HEIGHT - 6), FONT, 0.65, (255, 255, 255), 1, cv2.LINE_AA)
    for i, tile in enumerate(tiles):
        row, col = divmod(i, columns)
        y = top + GAP + row * (cell_h + GAP)
        x = GAP + col * (cell_w + GAP)
        sheet[y : y + tile.shape[0], x : x + tile.shape[1]] = tile
    return sheet
