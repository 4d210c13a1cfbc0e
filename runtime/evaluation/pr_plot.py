"""Precision/recall curves of an evaluation as one BGR image, drawn with OpenCV (no matplotlib).

A grid of small plots, one per class of the protocol in CLASSES order, and a last cell with the
protocol, the legend and the mAPs. Each plot shows, per IoU threshold, the interpolated precision
(the max precision at recall >= r) against recall, both axes 0..1, and how the protocol turns it
into its AP: the 11 sampled values as dots at the protocol's own recall points (11-point AP: their
mean; ``authors`` samples its 4th at 0.30000000000000004, so a curve reaching exactly 0.3 drops
there), or the area under the curve shaded (``sunrgbd``: the AP is that area). The title gives the
class, its number of ground-truth objects and its APs in percent. Classes without ground truth are
marked "no ground truth" (AP 0 by definition).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from a3d.runtime.evaluation.metric import ClassResult, EvalResult, eleven_point_values
from a3d.runtime.evaluation.protocols import APRule, Protocol

COLUMNS = 5
CELL_W, CELL_H = 300, 250
MARGIN_L, MARGIN_R, MARGIN_T, MARGIN_B = 40, 12, 44, 26
# One colour per threshold, in order (BGR): blue, orange, green, red.
CURVE_COLORS = ((180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214))  # cycled beyond 4
FONT = cv2.FONT_HERSHEY_SIMPLEX
INK, GRID, FAINT = (30, 30, 30), (225, 225, 225), (150, 150, 150)
SUBPIXEL = 4  # fixed-point bits for smooth anti-aliased polylines
AREA_TINT = 0.2  # shade under an area-AP curve: this much of the curve's colour over white
DOT_RADIUS = 4


def draw_pr_curves(result: EvalResult) -> np.ndarray:
    """The whole figure, uint8 BGR, (rows * CELL_H, COLUMNS * CELL_W, 3)."""
    cells = len(result.classes) + 1
    rows = -(-cells // COLUMNS)
    image = np.full((rows * CELL_H, COLUMNS * CELL_W, 3), 255, dtype=np.uint8)
    thresholds = result.config.iou_thresholds
    for i, cls in enumerate(result.classes):
        origin = ((i % COLUMNS) * CELL_W, (i // COLUMNS) * CELL_H)
        _draw_class(image, origin, cls, thresholds, result.config.protocol)
    last = len(result.classes)
    _draw_legend(image, ((last % COLUMNS) * CELL_W, (last // COLUMNS) * CELL_H), result)
    return image


def _color(k: int) -> tuple[int, int, int]:
    return CURVE_COLORS[k % len(CURVE_COLORS)]


def area_tint(k: int) -> tuple[int, int, int]:
    """The shade under threshold k's curve in an area-AP plot."""
    return tuple(round(255 + AREA_TINT * (c - 255)) for c in _color(k))


def sampled_points(cls: ClassResult, threshold: float, protocol: Protocol) -> np.ndarray:
    """(11, 2) rows (recall point, precision) that an 11-point AP averages; (0, 2) for area AP."""
    if protocol.ap_rule is APRule.AREA:
        return np.zeros((0, 2))
    values = eleven_point_values(cls.recall[threshold], cls.precision[threshold], protocol.recall_points)
    return np.stack([np.asarray(protocol.recall_points), values], axis=1)


def _per_threshold(value: Callable[[float], float], thresholds: Sequence[float]) -> str:
    """'41.2 / 30.5' : a fraction per threshold, in percent, in the legend's order."""
    return " / ".join(f"{100 * value(t):.1f}" for t in thresholds)


def _text(image: np.ndarray, text: str, xy: tuple[int, int], scale: float = 0.45, color=INK, bold=False):
    cv2.putText(image, text, xy, FONT, scale, color, 2 if bold else 1, cv2.LINE_AA)


def _draw_class(
    image: np.ndarray, origin: tuple[int, int], cls: ClassResult, thresholds, protocol: Protocol
) -> None:
    ox, oy = origin
    x0, y0 = ox + MARGIN_L, oy + MARGIN_T
    w, h = CELL_W - MARGIN_L - MARGIN_R, CELL_H - MARGIN_T - MARGIN_B
    _text(image, f"{cls.name}  (gt {cls.num_gt}, det {cls.num_det})", (ox + 8, oy + 17), 0.5, bold=True)
    if cls.present:
        _text(image, f"AP {_per_threshold(cls.ap.__getitem__, thresholds)}", (ox + 8, oy + 35), 0.42)
    else:
        _text(image, "no ground truth (AP 0)", (ox + 8, oy + 35), 0.42, FAINT)

    def fixed_point(rp: np.ndarray) -> np.ndarray:
        pts = np.stack([x0 + rp[:, 0] * w, y0 + (1 - rp[:, 1]) * h], axis=1)
        return np.round(pts * (1 << SUBPIXEL)).astype(np.int32).reshape(-1, 1, 2)

    curves = []
    if cls.present:
        for k, t in enumerate(thresholds):
            steps = _envelope_steps(cls.curve_corners(t)[:, :2])
            if len(steps) and steps[:, 0].max() > 0:  # no true positive: no curve
                curves.append((k, t, steps))
    if (
        protocol.ap_rule is APRule.AREA
    ):  # shade the areas (the APs) first; higher thresholds' (smaller) on top
        for k, _, steps in curves:
            closed = np.concatenate([[[0.0, 0.0]], steps, [[steps[-1, 0], 0.0]]])
            cv2.fillPoly(image, [fixed_point(closed)], area_tint(k), cv2.LINE_AA, SUBPIXEL)
    for k in range(11):  # grid at 0.1 steps, labels at 0, 0.5, 1
        gx, gy = x0 + round(k * w / 10), y0 + round((10 - k) * h / 10)
        cv2.line(image, (gx, y0), (gx, y0 + h), GRID, 1)
        cv2.line(image, (x0, gy), (x0 + w, gy), GRID, 1)
        if k % 5 == 0:
            label = f"{k / 10:g}"
            _text(image, label, (gx - 6, y0 + h + 15), 0.38, FAINT)
            _text(image, label, (x0 - 10 - 8 * len(label), gy + 4), 0.38, FAINT)
    cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), FAINT, 1)
    # Primary threshold drawn last and thinnest, so that coinciding curves all stay visible.
    for k, t, steps in reversed(curves):
        color = _color(k)
        cv2.polylines(image, [fixed_point(steps)], False, color, 2 + min(k, 4), cv2.LINE_AA, SUBPIXEL)
        for point in fixed_point(sampled_points(cls, t, protocol)).reshape(-1, 2):
            cv2.circle(
                image, tuple(int(v) for v in point), DOT_RADIUS << SUBPIXEL, color, -1, cv2.LINE_AA, SUBPIXEL
            )


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
    protocol = result.config.protocol
    _text(image, f"protocol: {protocol.name}", (ox + 8, oy + 20), 0.5, bold=True)
    how = "AP: the shaded area" if protocol.ap_rule is APRule.AREA else "AP: the mean of the 11 dots"
    _text(image, "interpolated precision vs recall", (ox + 8, oy + 38), 0.4)
    _text(image, how, (ox + 8, oy + 54), 0.4)
    y = oy + 76
    match = ">" if protocol.strict_iou else ">="
    for k, t in enumerate(result.config.iou_thresholds):
        color = _color(k)
        cv2.line(image, (ox + 10, y - 5), (ox + 40, y - 5), color, 3, cv2.LINE_AA)
        _text(image, f"3D IoU {match} {t:g}", (ox + 48, y))
        y += 20
    y += 6
    thresholds = result.config.iou_thresholds
    present = sum(c.present for c in result.classes)
    _text(image, f"mAP, all {len(result.classes)} classes:", (ox + 10, y))
    _text(image, _per_threshold(result.map_all, thresholds), (ox + 30, y + 18))
    _text(image, f"mAP, {present} classes with gt:", (ox + 10, y + 38))
    _text(image, _per_threshold(result.map_present, thresholds), (ox + 30, y + 56))
    y += 76
    nms = "no 2D NMS" if result.config.nms_iou is None else f"2D NMS {result.config.nms_iou:g}"
    if result.config.nms_iou is not None and protocol.nms_plus_one:
        nms += " (+1 px)"
    _text(image, f"{result.num_frames} frames, {nms}", (ox + 10, y), 0.42, FAINT)
