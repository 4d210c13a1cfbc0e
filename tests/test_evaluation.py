"""The paper's evaluation protocol (a3d.runtime.evaluation.metric) on hand-computed cases.

Fixture boxes are unit cubes at theta = 0 with R_tilt = I, shifted along x: two unit cubes whose
centres differ by d (0 <= d <= 1) along x overlap in a (1 - d) x 1 x 1 slab, so their 3D IoU is
(1 - d) / (1 + d): d = 0.25 -> 0.6, d = 0.5 -> 1/3, d = 0.7 -> 0.3 / 1.7 = 0.176.
"""

from __future__ import annotations

import numpy as np
import pytest

from a3d.runtime.evaluation.metric import (
    EvalConfig,
    evaluate,
    greedy_true_positives,
    interpolated_ap_11,
    retilt_boxes,
)
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, class_index
from a3d.runtime.structures.geometry import iou_3d, rtilt_from_pitch_roll
from tests.helpers.evaluation_cases import CHAIR, EYE, LAMP, TABLE, cube, dets, truth


def test_fixture_ious_are_the_hand_computed_ones() -> None:
    iou = iou_3d(np.array([cube(0.0)]), np.array([cube(0.25), cube(0.5), cube(0.7), cube(10.0)]), EYE)
    np.testing.assert_allclose(iou[0], [0.6, 1 / 3, 0.3 / 1.7, 0.0], atol=1e-9)


def test_perfect_detections_score_ap_one_and_map_counts_absent_classes_as_zero() -> None:
    rng = np.random.default_rng(0)
    classes = [CHAIR, TABLE, class_index("bed")]
    gt, det = {}, {}
    for f in range(4):
        ids = [classes[(f + k) % 3] for k in range(3)]
        boxes = [cube(3.0 * k, z=4.0 + f) for k in range(3)]
        gt[f"f{f}"] = truth(ids, boxes)
        det[f"f{f}"] = dets(f"f{f}", ids, rng.uniform(0.1, 1.0, 3), boxes)
    result = evaluate(gt, det)
    for c in result.classes:
        expected = 1.0 if class_index(c.name) in classes else 0.0
        assert c.ap == {0.25: expected, 0.5: expected}, c.name
        assert c.present == (expected == 1.0)
    assert result.map_present(0.25) == 1.0
    assert result.map_all(0.25) == pytest.approx(3 / NUM_CLASSES)
    assert len(result.absent_classes) == NUM_CLASSES - 3


def test_ranked_mix_of_true_and_false_positives_gives_the_hand_computed_11_point_ap() -> None:
    # 5 chairs: frame a at x=0 and x=3, frame b at x=0 and x=3, frame c at x=0.
    gt = {
        "a": truth([CHAIR, CHAIR], [cube(0), cube(3)]),
        "b": truth([CHAIR, CHAIR], [cube(0), cube(3)]),
        "c": truth([CHAIR], [cube(0)]),
    }
    # rank score frame box        IoU        @0.25       @0.5
    #  1   0.95   a    x=0        1          TP          TP
    #  2   0.90   a    x=0 again  1          FP (dup)    FP (dup)
    #  3   0.85   b    x=0        1          TP          TP
    #  4   0.80   c    x=0.25     0.6        TP          TP
    #  5   0.70   b    x=10       0          FP          FP
    #  6   0.60   c    x=0.7      0.176      FP          FP
    #  7   0.50   b    x=3.5      1/3        TP          FP
    det = {
        "a": dets("a", [CHAIR] * 2, [0.95, 0.90], [cube(0), cube(0)]),
        "b": dets("b", [CHAIR] * 3, [0.85, 0.70, 0.50], [cube(0), cube(10), cube(3.5)]),
        "c": dets("c", [CHAIR] * 2, [0.80, 0.60], [cube(0.25), cube(0.7)]),
    }
    chair = evaluate(gt, det).classes[CHAIR]
    # @0.25: TP FP TP TP FP FP TP -> precision 1, 1/2, 2/3, 3/4, 3/5, 1/2, 4/7
    #                                recall    .2, .2,  .4,  .6,  .6,  .6,  .8
    # max precision at recall >= t: t = 0, .1, .2 -> 1; t = .3, .4, .5, .6 -> 3/4;
    # t = .7, .8 -> 4/7; t = .9, 1 -> 0 (never reached).
    # AP = (3 * 1 + 4 * 3/4 + 2 * 4/7 + 2 * 0) / 11 = (6 + 8/7) / 11 = 50/77 = 0.64935...
    np.testing.assert_allclose(chair.precision[0.25], [1, 1 / 2, 2 / 3, 3 / 4, 3 / 5, 1 / 2, 4 / 7])
    np.testing.assert_allclose(chair.recall[0.25], [0.2, 0.2, 0.4, 0.6, 0.6, 0.6, 0.8])
    assert chair.ap[0.25] == pytest.approx(50 / 77, abs=1e-12)
    # @0.5 rank 7 is a FP: recall tops out at .6 -> t = 0, .1, .2 -> 1; t = .3 ... .6 -> 3/4; rest 0.
    # AP = (3 * 1 + 4 * 3/4) / 11 = 6/11
    assert chair.ap[0.5] == pytest.approx(6 / 11, abs=1e-12)
    # The curve's corners: every true positive, then the last detection.
    np.testing.assert_allclose(
        chair.curve_corners(0.25), [[0.2, 1, 0.95], [0.4, 2 / 3, 0.85], [0.6, 3 / 4, 0.8], [0.8, 4 / 7, 0.5]]
    )


def test_recall_exactly_three_tenths_reaches_the_point_t_equal_0_3() -> None:
    # 10 GT, ranked TP TP TP FP: recall .1 .2 .3 .3 at precision 1 1 1 3/4 -> t = 0 ... 0.3 -> 1.
    # AP = 4/11 (with t = 0.1 * 3 = 0.30000000000000004 it would wrongly be 3/11).
    recall = np.array([1, 2, 3, 3]) / 10
    precision = np.array([1, 1, 1, 0.75])
    assert interpolated_ap_11(recall, precision) == pytest.approx(4 / 11, abs=1e-12)


def test_duplicates_are_false_positives_and_matching_is_greedy_by_score_not_by_iou() -> None:
    gt = {"a": truth([CHAIR], [cube(0)])}
    # The better-placed detection (IoU 1) scores lower than a poorer one (IoU 0.6): the higher score
    # takes the object, the exact box is a duplicate.
    det = {"a": dets("a", [CHAIR, CHAIR], [0.9, 0.8], [cube(0.25), cube(0)])}
    chair = evaluate(gt, det).classes[CHAIR]
    np.testing.assert_allclose(chair.precision[0.25], [1.0, 0.5])
    np.testing.assert_allclose(chair.recall[0.25], [1.0, 1.0])
    assert chair.num_det == 2 and chair.ap[0.25] == 1.0


def test_a_detection_whose_best_ground_truth_is_taken_is_false_even_if_another_overlaps() -> None:
    # VOC semantics: GT at x=0 and x=0.6. Rank 2 (x=0.2) has IoU 0.8/1.2 = 0.667 with the first
    # (taken by rank 1) and 0.6/1.4 = 0.43 >= 0.25 with the second, but only its best one counts.
    gt = {"a": truth([CHAIR, CHAIR], [cube(0), cube(0.6)])}
    det = {"a": dets("a", [CHAIR, CHAIR], [0.9, 0.8], [cube(0), cube(0.2)])}
    chair = evaluate(gt, det).classes[CHAIR]
    np.testing.assert_allclose(chair.recall[0.25], [0.5, 0.5])
    np.testing.assert_allclose(chair.precision[0.25], [1.0, 0.5])


def test_a_class_with_detections_but_no_ground_truth_scores_zero_and_is_not_present() -> None:
    gt = {"a": truth([CHAIR], [cube(0)])}
    det = {"a": dets("a", [CHAIR, LAMP, LAMP], [0.5, 0.9, 0.8], [cube(0), cube(0), cube(5)])}
    result = evaluate(gt, det)
    lamp, chair = result.classes[LAMP], result.classes[CHAIR]
    assert (lamp.num_gt, lamp.num_det, lamp.present, lamp.ap[0.25]) == (0, 2, False, 0.0)
    np.testing.assert_array_equal(lamp.recall[0.25], [0.0, 0.0])
    assert chair.ap[0.25] == 1.0  # another class's detections do not touch it
    assert result.map_present(0.25) == 1.0
    assert result.map_all(0.25) == pytest.approx(1 / NUM_CLASSES)
    assert "lamp" in result.absent_classes and "chair" not in result.absent_classes


@pytest.mark.parametrize("detections", [{}, {"a": dets("a", [], [], [])}])
def test_no_detections_give_ap_zero_and_finite_maps(detections) -> None:
    gt = {"a": truth([CHAIR, TABLE], [cube(0), cube(3)]), "b": truth([], [])}
    result = evaluate(gt, detections)
    assert all(c.ap == {0.25: 0.0, 0.5: 0.0} for c in result.classes)
    assert result.classes[CHAIR].num_gt == 1 and result.classes[CHAIR].num_det == 0
    assert (result.map_all(0.25), result.map_present(0.25)) == (0.0, 0.0)
    assert set(result.frames_without_detections) == ({"a", "b"} - set(detections))


def test_maps_are_zero_not_nan_when_no_class_has_ground_truth() -> None:
    result = evaluate({"a": truth([], [])}, {"a": dets("a", [LAMP], [0.9], [cube(0)])})
    assert (result.map_all(0.5), result.map_present(0.5)) == (0.0, 0.0)
    assert len(result.absent_classes) == NUM_CLASSES


def test_iou_between_the_thresholds_counts_at_0_25_but_not_at_0_5() -> None:
    gt = {"a": truth([CHAIR], [cube(0)])}
    det = {"a": dets("a", [CHAIR], [0.9], [cube(0.5)])}  # IoU 1/3
    chair = evaluate(gt, det).classes[CHAIR]
    assert chair.ap == {0.25: 1.0, 0.5: 0.0}


def test_2d_nms_per_class_removes_an_overlapping_lower_score_detection_only_when_on() -> None:
    gt = {"a": truth([CHAIR], [cube(0)])}
    # Same-class 2D boxes with IoU 81/119 = 0.68 > 0.3: NMS drops the lower score, which here is the
    # one true positive. The lamp has the same 2D box but another class: never suppressed.
    det = {
        "a": dets(
            "a",
            [CHAIR, CHAIR, LAMP],
            [0.9, 0.8, 0.95],
            [cube(10), cube(0), cube(0)],
            boxes2d=[[0, 0, 10, 10], [1, 1, 11, 11], [0, 0, 10, 10]],
        )
    }
    with_nms = evaluate(gt, det, EvalConfig(nms_iou=0.3))
    without = evaluate(gt, det, EvalConfig(nms_iou=None))
    assert (with_nms.classes[CHAIR].num_det, with_nms.classes[CHAIR].ap[0.25]) == (1, 0.0)
    # Without NMS: FP then TP -> precision 0, 1/2 at recall 0, 1: every t -> 1/2.
    assert (without.classes[CHAIR].num_det, without.classes[CHAIR].ap[0.25]) == (2, 0.5)
    assert with_nms.classes[LAMP].num_det == without.classes[LAMP].num_det == 1


def _yaw(alpha: float) -> np.ndarray:
    """R_y(alpha): turns a tilt-frame yaw theta into theta + alpha."""
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def test_detections_in_another_tilt_frame_are_re_expressed_in_the_ground_truth_frame() -> None:
    # Two tilt frames that differ by a pure yaw of 0.5 rad share the vertical, so the re-expression
    # is exact: same centre and sizes, theta + 0.5. Thin boxes (2 x 0.2 footprint) make the yaw count.
    R_det = rtilt_from_pitch_roll(0.2, -0.1)
    R_gt = _yaw(0.5) @ R_det
    gt_boxes = np.array([[0.4, 0.3, 3.0, 2.0, 0.2, 1.0, 0.8], [-1.0, 0.5, 4.0, 1.2, 0.15, 0.7, -0.9]])
    det_boxes = gt_boxes - [0, 0, 0, 0, 0, 0, 0.5]  # the same objects in the detector's tilt frame
    np.testing.assert_allclose(retilt_boxes(det_boxes, R_det, R_gt), gt_boxes, atol=1e-12)
    gt = {"a": truth([CHAIR, TABLE], gt_boxes, R_gt)}
    det = {"a": dets("a", [CHAIR, TABLE], [0.9, 0.8], det_boxes, R_tilt=R_det)}
    result = evaluate(gt, det)
    assert result.retilted_frames == ["a"]
    assert result.classes[CHAIR].ap[0.5] == result.classes[TABLE].ap[0.5] == 1.0
    # Had theta been read in the ground truth's frame as it stands, both would miss at 0.5.
    assert np.all(iou_3d(det_boxes, gt_boxes, R_gt).diagonal() < 0.5)


def test_a_different_gravity_keeps_centre_and_sizes_and_projects_the_yaw() -> None:
    # Pitch/roll differences tilt the vertical: the fitted box keeps the camera-frame centre and the
    # edge lengths, and its yaw is the orientation vector projected on the ground truth's horizontal.
    R_det, R_gt = rtilt_from_pitch_roll(0.05, 0.08), rtilt_from_pitch_roll(0.25, -0.1)
    boxes = np.array([[0.4, 0.3, 3.0, 1.6, 0.8, 0.9, 0.6]])
    out = retilt_boxes(boxes, R_det, R_gt)
    np.testing.assert_allclose(out[:, :6], boxes[:, :6], atol=1e-12)
    orientation_cam = R_det.T @ [np.sin(0.6), 0.0, np.cos(0.6)]
    in_gt = R_gt @ orientation_cam
    assert out[0, 6] == pytest.approx(np.arctan2(in_gt[0], in_gt[2]), abs=1e-12)
    np.testing.assert_allclose(retilt_boxes(boxes, R_gt, R_gt), boxes, atol=1e-12)  # same frame


def test_detections_for_frames_without_ground_truth_are_rejected() -> None:
    with pytest.raises(ValueError, match="zzz"):
        evaluate({"a": truth([], [])}, {"zzz": dets("zzz", [], [], [])})


def _reference_greedy(best_gt, best_iou, threshold):
    """The VOC loop, literally."""
    taken, tp = set(), []
    for g, iou in zip(best_gt, best_iou, strict=True):
        hit = g >= 0 and iou >= threshold and g not in taken
        taken.update([g] if hit else [])
        tp.append(hit)
    return np.array(tp, dtype=bool)


def test_vectorised_greedy_matching_equals_the_voc_loop() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        n = int(rng.integers(0, 60))
        best_gt = rng.integers(-1, 8, n)
        best_iou = np.where(best_gt >= 0, rng.uniform(0, 1, n), 0.0)
        for thr in (0.25, 0.5):
            np.testing.assert_array_equal(
                greedy_true_positives(best_gt, best_iou, thr), _reference_greedy(best_gt, best_iou, thr)
            )


def test_vectorised_11_point_ap_equals_the_textbook_loop() -> None:
    rng = np.random.default_rng(2)
    for _ in range(50):
        n, num_gt = int(rng.integers(1, 40)), int(rng.integers(1, 20))
        tp = np.cumsum(rng.uniform(size=n) < 0.4)
        tp = np.minimum(tp, num_gt)
        recall, precision = tp / num_gt, tp / np.arange(1, n + 1)
        expected = np.mean(
            [
                max((p for r, p in zip(recall, precision, strict=True) if r >= k / 10), default=0.0)
                for k in range(11)
            ]
        )
        assert interpolated_ap_11(recall, precision) == pytest.approx(expected, abs=1e-12)


def test_classes_are_reported_in_the_canonical_order() -> None:
    result = evaluate({"a": truth([], [])}, {})
    assert [c.name for c in result.classes] == list(CLASSES)
