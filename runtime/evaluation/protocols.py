"""The named evaluation protocols of ``a3d-eval --protocol``: every rule that changes a number.

A number compared with a published table must be computed the way that table was. The three
protocols share the 3D IoU (``a3d.runtime.structures.geometry.iou_3d``: boxes rotated about
gravity, IoU in the ground truth's tilt frame; detections with another ``R_tilt`` are first
re-expressed in it) and the greedy matching (detections of the whole set by descending score,
each takes the ground truth of its class and frame with the largest IoU, the first of equal
maxima; a true positive if that IoU passes the threshold and the ground truth is still
unmatched, else a false positive). None of them has "difficult" or "don't care" objects: every
ground-truth object counts. They differ in:

``paper`` (the default): Deng & Latecki, CVPR 2017, as its text states it. Recall points exactly
    k/10; AP their mean; 2D NMS 0.3 on continuous boxes (IoU of edges, no +1); IoU >= threshold;
    ties in score broken by frame name, then order in the frame; the 19 classes. It is the
    default because it is the protocol the paper defines, with no artefact of one language's
    floating point or one codebase's pixel convention, and the one a3d's results were always
    reported in.
``authors``: bit-for-bit the evaluation of the authors' release (``matlab/eval/eval_3d.m``,
    ``d_eval_det_3d.m``, ``apply_nms.m``, ``nms.m``) as MATLAB runs it. Recall points are MATLAB's
    ``0:0.1:1``: the colon operator counts from both ends, k * 0.1 for k < 5 and
    1 - (10 - k) * 0.1 for k >= 5, so only the 4th point differs from k/10 (0.30000000000000004:
    a curve that reaches recall exactly 3/10 does not reach it). AP accumulated as
    ``ap = ap + p / 11`` in point order (a perfect class scores 1.0000000000000002). 2D NMS 0.3
    with widths and heights ``x2 - x1 + 1``, on the detections' ``box2d`` numbers as given.
    IoU >= threshold. Frames in image-number order (``imset``; names compared with their digit
    runs as numbers, "9" before "10"), ties in score kept in that order (MATLAB's ``sort`` is
    stable). The 19 classes.
``sunrgbd``: the 10-class SUN RGB-D protocol of VoteNet and mmdetection3d
    (``mmdet3d/evaluation/functional/indoor_eval.py``: ``eval_det_cls``, ``average_precision``
    with ``mode='area'``). AP is the area under the interpolated precision-recall curve (VOC
    2010+ "area"), stored as float32 as mmdetection3d does; precision ``tp / max(tp + fp, eps)``;
    a match needs IoU > threshold (strictly); no NMS (the detector's own); ties in score by frame
    name then order in the frame (mmdetection3d's unstable ``np.argsort`` leaves exact ties in an
    unspecified order). Classes: bed, table, sofa, chair, toilet, desk, dresser, night stand,
    bookshelf, bathtub; ground truth and detections of a3d's 9 other classes are ignored (and
    counted in the output). mmdetection3d averages over the classes that occur in the ground
    truth or the detections; a3d's "classes with GT" mAP is that number whenever every class
    with detections has ground truth (mmdetection3d would give NaN otherwise).

Pure data and small functions: the metric (``a3d.runtime.evaluation.metric``) applies them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from enum import Enum

from a3d.runtime.structures.classes import CLASSES


class APRule(str, Enum):
    """How a precision-recall curve becomes one number."""

    ELEVEN_POINT = "11-point"  # mean of the max precision at recall >= t over 11 recall points
    AREA = "area"  # area under the interpolated (monotone envelope) curve


class FrameOrder(str, Enum):
    """The order of frames in the ranked list, which breaks ties of equal scores across frames."""

    NAME = "name"  # plain string order of the frame names
    NUMBER = "number"  # digit runs compared as numbers ("9" before "10"): the release's image order


@dataclass(frozen=True)
class Protocol:
    """One named protocol; see the module docstring for the sources and the reasons."""

    name: str
    source: str
    classes: tuple[str, ...]  # scored classes, a subset of CLASSES; others are ignored
    ap_rule: APRule
    recall_points: tuple[float, ...]  # the 11 points of APRule.ELEVEN_POINT; () for APRule.AREA
    running_sum: bool  # 11-point AP as ap += p / 11 in point order (MATLAB), not the mean
    ap_float32: bool  # AP rounded to float32, as mmdetection3d stores it
    nms_iou: float | None  # 2D NMS on box2d before scoring; None: detections as given
    nms_plus_one: bool  # 2D NMS widths x2 - x1 + 1 (inclusive pixels) instead of x2 - x1
    strict_iou: bool  # a match needs IoU > threshold (True) or >= threshold (False)
    frame_order: FrameOrder

    @property
    def class_ids(self) -> tuple[int, ...]:
        """0-based CLASSES indices of the scored classes, in CLASSES order."""
        return tuple(i for i, name in enumerate(CLASSES) if name in self.classes)

    def frame_key(self, name: str) -> tuple:
        """Sort key of a frame name in this protocol's frame order."""
        if self.frame_order is FrameOrder.NAME:
            return (name,)
        return tuple((0, int(part), part) if part.isdigit() else (1, 0, part) for part in _DIGITS.split(name))

    def describe(self) -> dict:
        """Every rule, for eval.json."""
        return {
            "name": self.name,
            "source": self.source,
            "classes": list(self.classes),
            "ap": self.ap_rule.value,
            "recall_points": [repr(t) for t in self.recall_points],  # repr: 0.30000000000000004 stays
            "ap_accumulation": "running sum of p/11" if self.running_sum else "mean",
            "ap_float32": self.ap_float32,
            "nms_iou": self.nms_iou,
            "nms_box_convention": "x2 - x1 + 1 (inclusive pixels)" if self.nms_plus_one else "x2 - x1",
            "match": "IoU > threshold" if self.strict_iou else "IoU >= threshold",
            "frame_order": self.frame_order.value,
            "difficult_objects": "none: every ground-truth object counts",
        }

    def header(self) -> str:
        """One line for the table's header."""
        if self.ap_rule is APRule.AREA:
            ap = "AP = area under the interpolated PR curve"
        else:
            sums = ", running sum" if self.running_sum else ""
            points = "MATLAB 0:0.1:1" if self.recall_points != EXACT_TENTHS else "k/10"
            ap = f"11-point AP (recall {points}{sums})"
        nms = "no 2D NMS" if self.nms_iou is None else f"2D NMS {self.nms_iou:g}"
        if self.nms_iou is not None:
            nms += " (+1 pixel)" if self.nms_plus_one else " (continuous boxes)"
        match = ">" if self.strict_iou else ">="
        return f"protocol {self.name}: {ap}; {nms}; match IoU {match} t; {len(self.classes)} classes"


_DIGITS = re.compile(r"(\d+)")

EXACT_TENTHS: tuple[float, ...] = tuple(k / 10 for k in range(11))
"""0, 0.1, ..., 1 as the nearest doubles to k/10 (0.1 * 3 would be 0.30000000000000004)."""

MATLAB_COLON_TENTHS: tuple[float, ...] = tuple(k * 0.1 if k < 5 else 1.0 - (10 - k) * 0.1 for k in range(11))
"""MATLAB's ``0:0.1:1``: the colon operator computes a + k*d for the first half and b - (n-k)*d for
the second, so only the 4th value, 0.30000000000000004, differs from k/10 (GNU Octave computes
k * 0.1 throughout, where 0.6 and 0.7 differ too: an Octave run is not the reference here)."""

SUNRGBD_CLASSES: tuple[str, ...] = (
    "bed",
    "table",
    "sofa",
    "chair",
    "toilet",
    "desk",
    "dresser",
    "night stand",
    "bookshelf",
    "bathtub",
)  # VoteNet's / mmdetection3d's order

PAPER = Protocol(
    name="paper",
    source="Deng & Latecki, CVPR 2017: 19 classes, 3D IoU 0.25 (sec. 5), 2D NMS only (sec. 3.3); "
    "AP as PASCAL VOC's 11-point interpolation",
    classes=CLASSES,
    ap_rule=APRule.ELEVEN_POINT,
    recall_points=EXACT_TENTHS,
    running_sum=False,
    ap_float32=False,
    nms_iou=0.3,
    nms_plus_one=False,
    strict_iou=False,
    frame_order=FrameOrder.NAME,
)
AUTHORS = replace(  # the paper's protocol as the release's MATLAB computes it
    PAPER,
    name="authors",
    source="github.com/phoenixnn/Amodal3Det matlab/eval: eval_3d.m, d_eval_det_3d.m, apply_nms.m, nms.m",
    recall_points=MATLAB_COLON_TENTHS,
    running_sum=True,
    nms_plus_one=True,
    frame_order=FrameOrder.NUMBER,
)
SUNRGBD = Protocol(
    name="sunrgbd",
    source="VoteNet (Qi et al., ICCV 2019) as mmdetection3d's indoor_eval.py computes it (average_precision, "
    "mode='area')",
    classes=SUNRGBD_CLASSES,
    ap_rule=APRule.AREA,
    recall_points=(),
    running_sum=False,
    ap_float32=True,
    nms_iou=None,
    nms_plus_one=False,
    strict_iou=True,
    frame_order=FrameOrder.NAME,
)
PROTOCOLS: dict[str, Protocol] = {p.name: p for p in (PAPER, AUTHORS, SUNRGBD)}

assert set(SUNRGBD_CLASSES) <= set(CLASSES)  # a3d's 19 classes hold all 10
