"""The named protocols (a3d.runtime.evaluation.protocols) on small cases worked out by hand.

Each case is scored end to end by ``evaluate`` under two protocols that give different numbers,
with the expected values derived in the comments. Fixture boxes are unit cubes (tests/test_evaluation.py):
disjoint cubes have 3D IoU 0, equal ones 1; the default 2D boxes are disjoint, so NMS keeps all.
"""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.evaluation import pr_plot
from a3d.runtime.evaluation.metric import EvalConfig, area_ap, evaluate, greedy_true_positives
from a3d.runtime.evaluation.protocols import (
    AUTHORS,
    EXACT_TENTHS,
    MATLAB_COLON_TENTHS,
    PAPER,
    PROTOCOLS,
    SUNRGBD,
    SUNRGBD_CLASSES,
)
from a3d.runtime.structures.classes import CLASSES, class_index
from a3d.runtime.structures.geometry import batched_nms_2d, iou_2d
from tests.helpers.evaluation_cases import CHAIR, LAMP, cube, dets, truth


def score(gt, det, protocol, **config):
    return evaluate(gt, det, EvalConfig(protocol=protocol, **config))


def test_matlab_colon_points_differ_from_k_over_10_only_at_the_fourth() -> None:
    # 0:0.1:1 in MATLAB: 0.1 * k for k < 5, 1 - (10 - k) * 0.1 above; 0.1 * 3 = 0.30000000000000004,
    # while 1 - 3 * 0.1 = 0.7 and 1 - 4 * 0.1 = 0.6 land on the nearest doubles of 0.7 and 0.6.
    differ = [k for k in range(11) if MATLAB_COLON_TENTHS[k] != EXACT_TENTHS[k]]
    assert differ == [3]
    assert MATLAB_COLON_TENTHS[3] == 0.30000000000000004 and MATLAB_COLON_TENTHS[3] > 3 / 10
    assert EXACT_TENTHS[3] == 0.3 == 3 / 10


def test_authors_and_paper_differ_where_the_curve_reaches_recall_exactly_three_tenths() -> None:
    # 10 chairs in one frame; ranked TP TP TP FP TP:
    #   recall    .1 .2 .3 .3  .4
    #   precision  1  1  1 3/4 4/5
    gt = {"a": truth([CHAIR] * 10, [cube(3.0 * k) for k in range(10)])}
    boxes = [cube(0), cube(3), cube(6), cube(100), cube(9)]
    det = {"a": dets("a", [CHAIR] * 5, [0.9, 0.8, 0.7, 0.6, 0.5], boxes)}
    paper = score(gt, det, PAPER).classes[CHAIR].ap[0.25]
    authors = score(gt, det, AUTHORS).classes[CHAIR].ap[0.25]
    # paper, t = k/10: t = 0, .1, .2, .3 -> 1 (rank 3 has recall 3/10 >= 0.3); t = .4 -> 4/5; t >= .5 -> 0
    #   AP = (4 + 4/5) / 11 = 24/55 = 0.43636...
    assert paper == pytest.approx(24 / 55, abs=1e-15)
    # authors, t = 0.30000000000000004 > 3/10: the first recall >= t is .4 at rank 5 -> 4/5 there
    #   AP = (3 + 4/5 + 4/5) / 11 = 23/55 = 0.41818...: 1/55 = 0.018 lower
    assert authors == pytest.approx(23 / 55, abs=1e-15)
    assert paper - authors == pytest.approx(1 / 55, abs=1e-15)


def test_authors_plus_one_nms_drops_a_box_that_the_paper_keeps() -> None:
    # Same row, 2D boxes 9 wide: A = [0, 0, 9, 9], B = [5, 0, 14, 9].
    #   continuous: intersection 4 x 9 = 36, union 81 + 81 - 36 = 126 -> 2/7 = 0.286 <= 0.3: B kept
    #   +1 pixel:   intersection 5 x 10 = 50, areas 10 x 10, union 150 -> 1/3 > 0.3: B suppressed
    a, b = [0.0, 0.0, 9.0, 9.0], [5.0, 0.0, 14.0, 9.0]
    assert iou_2d(np.array([a]), np.array([b]))[0, 0] == pytest.approx(2 / 7, abs=1e-15)
    assert iou_2d(np.array([a]), np.array([b]), plus_one=True)[0, 0] == pytest.approx(1 / 3, abs=1e-15)
    # One chair; A (0.9) is a false positive in 3D, B (0.8) the true one.
    gt = {"f": truth([CHAIR], [cube(0)])}
    det = {"f": dets("f", [CHAIR, CHAIR], [0.9, 0.8], [cube(10), cube(0)], boxes2d=[a, b])}
    paper, authors = (score(gt, det, p).classes[CHAIR] for p in (PAPER, AUTHORS))
    # paper: FP, TP -> precision 0, 1/2 at recall 0, 1: every t sees 1/2 -> AP = 11 * (1/2) / 11 = 1/2
    assert (paper.num_det, paper.ap[0.25]) == (2, 0.5)
    # authors: B gone, A alone is a false positive -> AP 0
    assert (authors.num_det, authors.ap[0.25]) == (1, 0.0)


def _nms_m(boxes: np.ndarray, scores: np.ndarray, thresh: float) -> list[int]:
    """The release's nms.m, statement for statement (0-based indices)."""
    x1, y1, x2, y2 = boxes.T
    areas = (x2 - x1 + 1) * (y2 - y1 + 1)
    order = list(np.argsort(-scores, kind="stable"))  # MATLAB's sort(..., 'descend') is stable
    keep = []
    while order:
        i, rest = order[0], np.array(order[1:], dtype=np.int64)
        keep.append(int(i))
        w = np.maximum(0.0, np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]) + 1)
        h = np.maximum(0.0, np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]) + 1)
        inter = w * h
        ovr = inter / (areas[i] + areas[rest] - inter)
        order = list(rest[ovr <= thresh])
    return keep


def test_plus_one_nms_keeps_exactly_what_the_release_nms_m_keeps() -> None:
    rng = np.random.default_rng(7)
    for _ in range(30):
        n = int(rng.integers(2, 40))
        corner = rng.integers(0, 60, (n, 2)).astype(float)  # integer pixels: many exact-threshold ties
        boxes = np.hstack([corner, corner + rng.integers(0, 25, (n, 2))])
        scores = rng.integers(0, 5, n) / 4.0  # tied scores too
        for thr in (0.3, 0.5):
            got = batched_nms_2d(boxes, scores, np.zeros(n, np.int64), thr, plus_one=True).tolist()
            assert got == _nms_m(boxes, scores, thr)


def test_sunrgbd_area_ap_differs_from_the_11_point_ap_and_ignores_other_classes() -> None:
    # 2 chairs; ranked TP FP TP: recall .5 .5 1, precision 1 1/2 2/3. A lamp (not a SUN RGB-D class)
    # with its detection: scored by paper, ignored by sunrgbd.
    gt = {"a": truth([CHAIR, CHAIR, LAMP], [cube(0), cube(3), cube(20)])}
    det = {"a": dets("a", [CHAIR] * 3 + [LAMP], [0.9, 0.8, 0.7, 0.6], [cube(0), cube(10), cube(3), cube(20)])}
    paper, sun = score(gt, det, PAPER), score(gt, det, SUNRGBD)
    # paper 11-point: t = 0 ... .5 -> 1 (6 points), t = .6 ... 1 -> 2/3 (5 points)
    #   AP = (6 + 5 * 2/3) / 11 = 28/33 = 0.84848...
    assert paper.classes[CHAIR].ap[0.25] == pytest.approx(28 / 33, abs=1e-15)
    # sunrgbd area: envelope 1 on recall (0, .5], 2/3 on (.5, 1] -> AP = .5 * 1 + .5 * 2/3 = 5/6 = 0.83333...,
    #   stored as float32 like mmdetection3d
    chair = next(c for c in sun.classes if c.name == "chair")
    assert chair.ap[0.25] == float(np.float32(5 / 6))
    assert chair.ap[0.25] == pytest.approx(5 / 6, abs=1e-7)
    assert [c.name for c in sun.classes] == [c for c in CLASSES if c in SUNRGBD_CLASSES]
    assert (sun.ignored_gt, sun.ignored_det) == (1, 1) and (paper.ignored_gt, paper.ignored_det) == (0, 0)
    assert paper.classes[LAMP].ap[0.25] == 1.0
    # mAP over the classes with GT: chair alone for sunrgbd; chair and lamp for paper
    assert sun.map_present(0.25) == float(np.float32(5 / 6))
    assert paper.map_present(0.25) == pytest.approx((28 / 33 + 1) / 2, abs=1e-15)


def test_area_ap_is_mmdetection3d_average_precision_area_step_for_step() -> None:
    # mmdetection3d pads (0, 0) and (1, 0), takes the running max from the right and sums
    # (recall step) * precision: recall .25 .25 .5 .75, precision 1 1/2 2/3 3/4
    #   envelope 1 on (0, .25], 3/4 on (.25, .75] -> .25 * 1 + .5 * 3/4 = 0.625
    recall = np.array([0.25, 0.25, 0.5, 0.75])
    precision = np.array([1.0, 0.5, 2 / 3, 0.75])
    assert area_ap(recall, precision) == 0.625
    assert area_ap(np.zeros(0), np.zeros(0)) == 0.0


def test_sunrgbd_needs_iou_above_the_threshold_the_others_at_least_it() -> None:
    best_gt, best_iou = np.array([0, 1]), np.array([0.25, 0.3])
    assert greedy_true_positives(best_gt, best_iou, 0.25).tolist() == [True, True]
    assert greedy_true_positives(best_gt, best_iou, 0.25, strict=True).tolist() == [False, True]


def test_authors_break_score_ties_in_image_number_order() -> None:
    # Frames "9" and "10", one chair each, one detection each at the same score: "10" a TP, "9" a FP.
    gt = {"9": truth([CHAIR], [cube(0)]), "10": truth([CHAIR], [cube(0)])}
    det = {"9": dets("9", [CHAIR], [0.5], [cube(10)]), "10": dets("10", [CHAIR], [0.5], [cube(0)])}
    # paper, name order ("10" < "9"): TP, FP -> precision 1, 1/2 at recall 1/2: t <= .5 -> 1, AP = 6/11
    assert score(gt, det, PAPER).classes[CHAIR].ap[0.25] == pytest.approx(6 / 11, abs=1e-15)
    # authors, image order (9 < 10): FP, TP -> precision 0, 1/2 at recall 0, 1/2: t <= .5 -> 1/2, AP = 3/11
    assert score(gt, det, AUTHORS).classes[CHAIR].ap[0.25] == pytest.approx(3 / 11, abs=1e-15)


def test_authors_sum_p_over_11_point_by_point_like_matlab() -> None:
    # A perfect class: eleven 1s. Their mean is exactly 1; MATLAB's ap = ap + p/11, eleven times
    # 1/11 = 0.090909090909090912 (rounded up), accumulates to 1.0000000000000002.
    gt = {"a": truth([CHAIR], [cube(0)])}
    det = {"a": dets("a", [CHAIR], [0.9], [cube(0)])}
    assert score(gt, det, PAPER).classes[CHAIR].ap[0.25] == 1.0
    assert score(gt, det, AUTHORS).classes[CHAIR].ap[0.25] == 1.0000000000000002


def test_the_protocols_own_nms_unless_overridden() -> None:
    assert EvalConfig(protocol=SUNRGBD).nms_iou is None and EvalConfig(protocol=AUTHORS).nms_iou == 0.3
    assert EvalConfig().protocol is PAPER and EvalConfig().nms_iou == 0.3
    overridden = EvalConfig(nms_iou=0.5, protocol=SUNRGBD)
    assert overridden.nms_iou == 0.5 and not overridden.protocol_nms
    assert set(PROTOCOLS) == {"paper", "authors", "sunrgbd"}
    assert {class_index(c) for c in SUNRGBD_CLASSES} == set(SUNRGBD.class_ids)


def test_the_picture_shows_each_protocols_own_interpolation() -> None:
    # The recall-step case: paper's dot at t = 0.3 sits at precision 1, the authors' at 4/5;
    # sunrgbd has no dots (its AP is the shaded area).
    gt = {"a": truth([CHAIR] * 10, [cube(3.0 * k) for k in range(10)])}
    boxes = [cube(0), cube(3), cube(6), cube(100), cube(9)]
    det = {"a": dets("a", [CHAIR] * 5, [0.9, 0.8, 0.7, 0.6, 0.5], boxes)}
    results = {p.name: score(gt, det, p) for p in (PAPER, AUTHORS, SUNRGBD)}
    points = {}
    for name, result in results.items():
        chair = next(c for c in result.classes if c.name == "chair")
        points[name] = pr_plot.sampled_points(chair, 0.25, result.config.protocol)
    np.testing.assert_array_equal(points["paper"][:, 1], [1, 1, 1, 1, 0.8, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(points["authors"][:, 1], [1, 1, 1, 0.8, 0.8, 0, 0, 0, 0, 0, 0])
    assert points["sunrgbd"].shape == (0, 2)

    # Pixels: dots at precision 0 beyond the curve's end (recall .4) in the 11-point pictures only;
    # the shade (the area) in the sunrgbd picture only.
    blue = np.array(pr_plot.CURVE_COLORS[0])
    for name, result in results.items():
        image = pr_plot.draw_pr_curves(result)
        index = [c.name for c in result.classes].index("chair")
        ox = (index % pr_plot.COLUMNS) * pr_plot.CELL_W + pr_plot.MARGIN_L
        oy = (index // pr_plot.COLUMNS) * pr_plot.CELL_H + pr_plot.MARGIN_T
        w = pr_plot.CELL_W - pr_plot.MARGIN_L - pr_plot.MARGIN_R
        h = pr_plot.CELL_H - pr_plot.MARGIN_T - pr_plot.MARGIN_B
        x_axis = image[oy + h - 2 : oy + h + 3, ox + int(0.45 * w) : ox + w + 5]
        dots = np.all(x_axis == blue, axis=2).sum()
        plot = image[oy : oy + h, ox : ox + w]
        # Both thresholds have the same curve here: the 0.5 shade lies on top of the 0.25 one.
        shade = sum(np.all(plot == np.array(pr_plot.area_tint(k)), axis=2).sum() for k in (0, 1))
        if name == "sunrgbd":  # the area under the curve is 0.38 of the plot, less the grid lines
            assert dots == 0 and 0.3 * w * h < shade < 0.38 * w * h
        else:
            assert dots > 6 * 5 and shade == 0  # six dots, t = .5 ... 1
