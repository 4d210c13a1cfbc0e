"""Precision/recall curves of an evaluation as one BGR image, drawn with OpenCV (no matplotlib).

A grid of small plots, one per class in CLASSES order, and a last cell with the legend and the
mAPs. Each plot shows, per IoU threshold, the interpolated precision (the max precision at recall
>= r, what the 11-point AP averages) against recall, both axes 0..1; its title gives the class,
its number of ground-truth objects and its APs in percent. Classes without ground truth are
marked "no ground truth" (AP 0 by definition).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from a3d.runtime.evaluation.metric import ClassResult, EvalResult

COLUMNS = 5
CELL_W, CELL_H = 300, 250
MARGIN_L, MARGIN_R, MARGIN_T, MARGIN_B = 40, 12, 44, 26
# One colour per threshold, in order (BGR): blue, orange, green, red.
CURVE_COLORS = ((180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214))  # cycled beyond 4
FONT = cv2.FONT_HERSHEY_SIMPLEX
INK, GRID, FAINT = (30, 30, 30), (225, 225, 225), (150, 150, 150)
SUBPIXEL = 4  # fixed-point bits for smooth anti-aliased polylines


def draw_pr_curves(result: EvalResult) -> np.ndarray:
    """The whole figure, uint8 BGR, (rows * CELL_H, COLUMNS * CELL_W, 3)."""
    cells = len(result.classes) + 1
    rows = -(-cells // COLUMNS)
    image = np.full((rows * CELL_H, COLUMNS * CELL_W, 3), 255, dtype=np.uint8)
    thresholds = result.config.iou_thresholds
    for i, cls in enumerate(result.classes):
        origin = ((i % COLUMNS) * CELL_W, (i // COLUMNS) * CELL_H)
        _draw_class(image, origin, cls, thresholds)
    last = len(result.classes)
    _draw_legend(image, ((last % COLUMNS) * CELL_W, (last // COLUMNS) * CELL_H), result)
    return image


def _color(k: int) -> tuple[int, int, int]:
    return CURVE_COLORS[k % len(CURVE_COLORS)]


def _per_threshold(value: Callable[[float], float], thresholds: Sequence[float]) -> str:
    """'41.2 / 30.5' : a fraction per threshold, in percent, in the legend's order."""
    return " / ".join(f"{100 * value(t):.1f}" for t in thresholds)


def _text(image: np.ndarray, text: str, xy: tuple[int, int], scale: float = 0.45, color=INK, bold=False):
    cv2.putText(image, text, xy, FONT, scale, color, 2 if bold else 1, cv2.LINE_AA)


def _draw_class(image: np.ndarray, origin: tuple[int, int], cls: ClassResult, thresholds) -> None:
    ox, oy = origin
    x0, y0 = ox + MARGIN_L, oy + MARGIN_T
    w, h = CELL_W - MARGIN_L - MARGIN_R, CELL_H - MARGIN_T - MARGIN_B
    _text(image, f"{cls.name}  (gt {cls.num_gt}, det {cls.num_det})", (ox + 8, oy + 17), 0.5, bold=True)
    if cls.present:
        _text(image, f"AP {_per_threshold(cls.ap.__getitem__, thresholds)}", (ox + 8, oy + 35), 0.42)
    else:
        _text(image, "no ground truth (AP 0)", (ox + 8, oy + 35), 0.42, FAINT)
    for k in range(11):  # grid at 0.1 steps, labels at 0, 0.5, 1
        gx, gy = x0 + round(k * w / 10), y0 + round((10 - k) * h / 10)
        cv2.line(image, (gx, y0), (gx, y0 + h), GRID, 1)
        cv2.line(image, (x0, gy), (x0 + w, gy), GRID, 1)
        if k % 5 == 0:
            label = f"{k / 10:g}"
            _text(image, label, (gx - 6, y0 + h + 15), 0.38, FAINT)
            _text(image, label, (x0 - 10 - 8 * len(label), gy + 4), 0.38, FAINT)
    cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), FAINT, 1)
    if not cls.present:
        return
    # Primary threshold drawn last and thinnest, so that coinciding curves all stay visible.
    for k, t in reversed(list(enumerate(thresholds))):
        color = _color(k)
        steps = _envelope_steps(cls.curve_corners(t)[:, :2])
        if len(steps) and steps[:, 0].max() > 0:  # no true positive: no curve
            pts = np.stack([x0 + steps[:, 0] * w, y0 + (1 - steps[:, 1]) * h], axis=1)
            fixed = np.round(pts * (1 << SUBPIXEL)).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(image, [fixed], False, color, 2 + min(k, 4), cv2.LINE_AA, SUBPIXEL)


def _envelope_steps(corners: np.ndarray) -> np.ndarray:
    """Vertices of the interpolated precision step curve from (recall, precision) corner rows."""
    if len(corners) == 0:
        return np.zeros((0, 2))
    recall = corners[:, 0]
    level = np.maximum.accumulate(corners[::-1, 1])[::-1]  # max precision at recall >= this corner
    starts = np.concatenate([[0.0], recall[:-1]])
    return np.stack([np.stack([starts, level], 1), np.stack([recall, level], 1)], axis=1).reshape(-1, 2)


def _draw_legend(image: np.ndarray, origin: tuple[int, int], result: EvalResult) -> None:
    ox, oy = origin
    _text(image, "interpolated precision vs recall", (ox + 8, oy + 22), 0.45, bold=True)
    y = oy + 52
    for k, t in enumerate(result.config.iou_thresholds):
        color = _color(k)
        cv2.line(image, (ox + 10, y - 5), (ox + 40, y - 5), color, 3, cv2.LINE_AA)
        _text(image, f"3D IoU >= {t:g}", (ox + 48, y))
        y += 20
    y += 6
    thresholds = result.config.iou_thresholds
    present = sum(c.present for c in result.classes)
    _text(image, f"mAP, all {len(result.classes)} classes:", (ox + 10, y))
    _text(image, _per_threshold(result.map_all, thresholds), (ox + 30, y + 18))
    _text(image, f"mAP, {present} classes with gt:", (ox + 10, y + 42))
    _text(image, _per_threshold(result.map_present, thresholds), (ox + 30, y + 60))
    y += 88
    nms = "off" if result.config.nms_iou is None else f"2D NMS {result.config.nms_iou:g}"
    _text(image, f"{result.num_frames} frames, {nms}", (ox + 10, y), 0.42, FAINT)
