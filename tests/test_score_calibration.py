"""Score calibration (a3d.runtime.postprocess.score_calibration): the fit, its application in
the pipeline, and that it leaves every class's ranking, hence every AP, as it was."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate
from a3d.runtime.pipeline import PipelineConfig, detect
from a3d.runtime.postprocess.score_calibration import ScoreCalibration, fit_calibration, logit
from a3d.runtime.structures.classes import NUM_CLASSES
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import Intrinsics
from tests.helpers.runtime_frames import FakeModel, fake_metadata, scene

TRUE_SLOPE = np.array([2.0, 0.5, 1.0])
TRUE_INTERCEPT = np.array([-3.0, 0.5, 0.0])


def _platt_sample(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detections of three classes whose right/wrong flags follow known Platt maps."""
    rng = np.random.default_rng(seed)
    classes = rng.integers(0, 3, n)
    scores = rng.uniform(0.001, 0.999, n)
    chance = 1 / (1 + np.exp(-(TRUE_SLOPE[classes] * logit(scores) + TRUE_INTERCEPT[classes])))
    return scores, classes, rng.random(n) < chance


def test_the_fit_recovers_known_maps_and_a_class_without_detections_takes_the_pooled_one() -> None:
    scores, classes, right = _platt_sample(30000)
    cal = fit_calibration(scores, classes, right, 4, 0.25)
    # ~10000 detections per class: the maximum-likelihood error is a few hundredths
    np.testing.assert_allclose(cal.slope[:3], TRUE_SLOPE, atol=0.12)
    np.testing.assert_allclose(cal.intercept[:3], TRUE_INTERCEPT, atol=0.2)
    pooled = fit_calibration(scores, np.zeros_like(classes), right, 1, 0.25)
    assert cal.slope[3] == pytest.approx(pooled.slope[0], abs=0.02)
    assert cal.intercept[3] == pytest.approx(pooled.intercept[0], abs=0.05)
    assert cal.iou == 0.25


def test_a_class_with_few_detections_is_pulled_toward_the_pooled_map() -> None:
    scores, classes, right = _platt_sample(30000)
    few = np.flatnonzero(classes == 1)[:20]
    keep = np.concatenate([np.flatnonzero(classes != 1), few])
    assert 0 < right[few].sum() < len(few)
    cal = fit_calibration(scores[keep], classes[keep], right[keep], 3, 0.25)
    alone = fit_calibration(scores[few], np.zeros(len(few), int), right[few], 1, 0.25)
    pooled = fit_calibration(scores[keep], np.zeros(len(keep), int), right[keep], 1, 0.25)
    # the shrunk fit lies between the class's own (20 detections) and the pooled one
    for name in ("slope", "intercept"):
        own, shared, shrunk = (getattr(c, name)[i] for c, i in ((alone, 0), (pooled, 0), (cal, 1)))
        assert min(own, shared) < shrunk < max(own, shared), name
    assert np.isfinite(cal.slope).all() and (cal.slope > 0).all()


def test_separable_flags_give_a_finite_increasing_map() -> None:
    scores = np.linspace(0.01, 0.99, 200)
    cal = fit_calibration(scores, np.zeros(200, int), scores > 0.6, 1, 0.25)
    out = cal.apply(scores, np.zeros(200, int))
    assert np.isfinite(cal.slope).all() and np.all(np.diff(out) > 0)
    assert out[scores < 0.5].max() < 0.5 < out[scores > 0.7].min()


@pytest.mark.parametrize("flags", [np.ones(50, bool), np.zeros(50, bool)])
def test_all_right_or_all_wrong_cannot_be_fitted(flags: np.ndarray) -> None:
    with pytest.raises(ValueError, match="need both right and wrong"):
        fit_calibration(np.linspace(0.1, 0.9, 50), np.zeros(50, int), flags, 2, 0.25)


def test_apply_is_strictly_increasing_per_class_and_both_forms_agree() -> None:
    rng = np.random.default_rng(1)
    cal = ScoreCalibration(rng.uniform(0.1, 3, NUM_CLASSES), rng.normal(0, 2, NUM_CLASSES), 0.25)
    matrix = rng.uniform(0, 1, (500, NUM_CLASSES))
    out = cal.apply(matrix)
    for c in range(NUM_CLASSES):
        order = np.argsort(matrix[:, c])
        assert np.all(np.diff(out[order, c]) > 0)
    rows, cols = rng.integers(0, 500, 300), rng.integers(0, NUM_CLASSES, 300)
    np.testing.assert_array_equal(cal.apply(matrix[rows, cols], cols), out[rows, cols])
    assert np.all((out > 0) & (out < 1))
    with pytest.raises(ValueError, match="expected"):
        cal.apply(matrix[:, :5])


@pytest.mark.parametrize("slope", [np.zeros(NUM_CLASSES), np.full(NUM_CLASSES, np.nan), np.ones(3)])
def test_a_map_that_is_not_increasing_or_not_one_per_class_is_refused(slope: np.ndarray) -> None:
    with pytest.raises(ValueError):
        ScoreCalibration(slope, np.zeros(NUM_CLASSES), 0.25)


def _frame(seed: int) -> Frame:
    color, depth = scene(seed)
    height, width = depth.shape
    K = Intrinsics(500.0, 500.0, width / 2, height / 2)
    return Frame(name=f"f{seed}", color=color, depth=depth, intrinsics=K, R_tilt=np.eye(3))


def test_the_pipeline_applies_the_models_calibration_before_selection_and_can_leave_it_off() -> None:
    rng = np.random.default_rng(2)
    cal = ScoreCalibration(rng.uniform(0.3, 2, NUM_CLASSES), rng.normal(-1, 1, NUM_CLASSES), 0.25)
    plain, calibrated = fake_metadata(), fake_metadata(score_calibration=cal)
    frame = _frame(3)
    raw = detect(frame, FakeModel(plain), PipelineConfig.from_metadata(plain))
    got = detect(frame, FakeModel(calibrated), PipelineConfig.from_metadata(calibrated))
    off = detect(frame, FakeModel(calibrated), PipelineConfig.from_metadata(calibrated, raw_scores=True))
    assert len(raw.scores) > 20
    # the same detections (per-class order kept), each score mapped by its class's map
    key = lambda d: sorted(zip(d.class_ids.tolist(), d.boxes2d.round(3).tolist(), strict=True))  # noqa: E731
    assert key(got) == key(raw) == key(off)
    index = {
        (c, tuple(b)): s
        for c, b, s in zip(raw.class_ids, raw.boxes2d.round(3).tolist(), raw.scores, strict=True)
    }
    expected = [
        index[(c, tuple(b))] for c, b in zip(got.class_ids, got.boxes2d.round(3).tolist(), strict=True)
    ]
    np.testing.assert_allclose(got.scores, cal.apply(np.array(expected), got.class_ids), rtol=1e-12)
    np.testing.assert_array_equal(off.scores, raw.scores)
    # a threshold now applies to the calibrated score
    cut = float(np.median(got.scores))
    config = PipelineConfig.from_metadata(calibrated, min_score=cut)
    kept = detect(frame, FakeModel(calibrated), config)
    assert len(kept.scores) == int(np.sum(got.scores >= cut)) and kept.scores.min() >= cut


def test_calibrated_scores_leave_every_ap_as_it_was() -> None:
    frames = [_frame(s) for s in range(3)]
    rng = np.random.default_rng(4)
    cal = ScoreCalibration(rng.uniform(0.3, 2, NUM_CLASSES), rng.normal(-1, 1, NUM_CLASSES), 0.25)
    plain, calibrated = fake_metadata(), fake_metadata(score_calibration=cal)
    raw = {f.name: detect(f, FakeModel(plain), PipelineConfig.from_metadata(plain)) for f in frames}
    got = {f.name: detect(f, FakeModel(calibrated), PipelineConfig.from_metadata(calibrated)) for f in frames}
    # ground truth: a third of the raw detections' own boxes, so every class has right and wrong ones
    truth = {name: FrameTruth(d.class_ids[::3], d.boxes3d[::3], d.R_tilt) for name, d in raw.items()}
    config = EvalConfig(iou_thresholds=(0.25,))
    before, after = evaluate(truth, raw, config), evaluate(truth, got, config)
    aps = [c.ap[0.25] for c in before.classes]
    assert sum(a > 0 for a in aps) >= 3
    assert [c.ap[0.25] for c in after.classes] == pytest.approx(aps, abs=1e-12)
    assert not np.allclose(np.concatenate([d.scores for d in got.values()]),
                           np.concatenate([d.scores for d in raw.values()]))  # fmt: skip


def test_calibrate_fits_a_trained_model_on_the_samples_and_reports_what_it_saw() -> None:
    """a3d-export's step on a real model (the pinned one, never calibrated): every annotated sample
    frame, the evaluator's flags."""
    from a3d.export.score_calibration import calibrate
    from a3d.runtime.evaluation.truth import load_truth
    from a3d.runtime.network.model import DetectorModel
    from tests.helpers.samples import PINNED_MODEL, SAMPLES

    calibration, report = calibrate(DetectorModel.load(PINNED_MODEL, threads=2), SAMPLES, "test")
    truth, _ = load_truth(SAMPLES)
    assert report["frames"] == len(truth) and report["iou"] == calibration.iou == 0.25
    assert 0 < report["right"] < report["detections"]
    assert calibration.slope.shape == (NUM_CLASSES,) and np.all(calibration.slope > 0)
    shares = report["right_share_at_0.5"]
    # fitted on these frames, the calibrated scores >= 0.5 are right at least half the time
    assert shares["calibrated"]["right_share"] >= 0.5
    assert shares["softmax"]["detections"] > 0


def test_a3d_run_writes_calibrated_scores_and_raw_scores_on_request(tmp_path, capsys) -> None:
    """A network without calibration (the pinned model) and with one in its file, through a3d-run:
    the same detections, scores mapped; --raw-scores gives the softmax back; the summary says which."""
    import onnx

    from a3d.export.onnx_export import save_model
    from a3d.runtime.cli import run as run_cli
    from a3d.runtime.io.detections_io import read_detections
    from a3d.runtime.network.model import DetectorModel
    from tests.helpers.samples import PINNED_MODEL, SAMPLES

    rng = np.random.default_rng(5)
    cal = ScoreCalibration(rng.uniform(1.0, 2.0, NUM_CLASSES), rng.normal(-1, 0.5, NUM_CLASSES), 0.25)
    metadata = DetectorModel.load(PINNED_MODEL, threads=1).metadata
    model = tmp_path / "calibrated.onnx"
    save_model(onnx.load(str(PINNED_MODEL)), replace(metadata, score_calibration=cal), model)
    lines = {}
    for name, extra in (("plain", ["--model", str(PINNED_MODEL)]), ("calibrated", ["--model", str(model)]),
                        ("raw", ["--model", str(model), "--raw-scores"])):  # fmt: skip
        out = tmp_path / f"{name}.jsonl"
        assert run_cli.main([str(SAMPLES), "--output", str(out), "--headless", *extra]) == 0
        summary = [line for line in capsys.readouterr().err.splitlines() if "the viewer's threshold" in line]
        assert ("calibrated scores" in summary[0]) == (name == "calibrated"), summary
        lines[name] = {d.frame: d for d in read_detections(out)}
    for frame, plain in lines["plain"].items():
        got, raw = lines["calibrated"][frame], lines["raw"][frame]
        np.testing.assert_array_equal(raw.scores, plain.scores)
        key = lambda d: sorted(zip(d.class_ids.tolist(), d.boxes2d.tolist(), strict=True))  # noqa: E731
        assert key(got) == key(plain)
        by_box = {
            (c, tuple(b)): s
            for c, b, s in zip(plain.class_ids, plain.boxes2d.tolist(), plain.scores, strict=True)
        }
        before = np.array(
            [by_box[(c, tuple(b))] for c, b in zip(got.class_ids, got.boxes2d.tolist(), strict=True)]
        )
        # the lines round scores to 1e-6; slopes >= 1 keep the map's derivative below ~2 everywhere
        np.testing.assert_allclose(got.scores, cal.apply(before, got.class_ids), atol=1e-5)
