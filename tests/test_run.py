"""The runtime's network inputs, post-processing and per-frame pipeline (a3d-run's core).

Post-processing is checked on known answers and against the one-detection-at-a-time greedy
reference (geometry's batched_nms_2d); the pipeline runs on tiny frames
written here with a fake model (same interface as DetectorModel: ``.metadata``, ``.run``).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime import pipeline
from a3d.runtime.cli import eval as eval_cli
from a3d.runtime.cli import run as run_cli
from a3d.runtime.evaluation.metric import FrameTruth, evaluate
from a3d.runtime.frontend.proposals import ProposalConfig, proposal_config_from_dict
from a3d.runtime.io.detections_io import read_detections, write_detections
from a3d.runtime.network.network_input import network_inputs, scale_boxes, with_batch_index
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR, color_input, depth_input
from a3d.runtime.pipeline import PipelineConfig, detect, detect_frames, detect_frames_auto, overlap_pays
from a3d.runtime.postprocess.select import decode_detections, select_detections
from a3d.runtime.sources.folder import (
    FolderSource,
    write_frame,
)
from a3d.runtime.sources.proposals_file import PrecomputedProposals, write_precomputed_proposals
from a3d.runtime.structures.classes import NUM_CLASSES, NUM_OUTPUTS, class_index
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import (
    batched_nms_2d,
    box_corners_camera,
    rtilt_from_pitch_roll,
)
from tests.helpers.runtime_frames import (
    FakeModel,
    H,
    W,
    assert_same_detections,
    scene,
    write_scene_folder,
)

# ----------------------------------------------------------------------------- network inputs


def test_scale_boxes_maps_the_image_extent_exactly() -> None:
    h, w = 427, 561
    color, depth, (sx, sy) = network_inputs(
        np.zeros((h, w, 3), np.uint8), np.ones((h, w), np.float32), 0.4, 10.0
    )
    assert color.shape == depth.shape == (3, 171, 224)  # round(427 * 0.4), round(561 * 0.4)
    assert (sx, sy) == (224 / 561, 171 / 427)
    full = scale_boxes(np.array([[-0.5, -0.5, w - 0.5, h - 0.5]]), sx, sy)
    np.testing.assert_allclose(full, [[-0.5, -0.5, 223.5, 170.5]], atol=1e-12)
    # A pixel's centre maps to the centre of the area it covers: pixel 10 at scale 1/2 -> 4.75.
    np.testing.assert_allclose(
        scale_boxes(np.array([[10.0, 10.0, 11.0, 11.0]]), 0.5, 0.5), [[4.75, 4.75, 5.25, 5.25]]
    )
    np.testing.assert_array_equal(with_batch_index(np.ones((2, 4)), 3)[:, 0], [3.0, 3.0])


def test_network_inputs_at_native_scale_are_the_preprocessed_frame() -> None:
    color, depth = scene(0)
    c, d, scale = network_inputs(color, depth, 1.0, 10.0)
    assert scale == (1.0, 1.0)
    np.testing.assert_array_equal(c, color_input(color))
    np.testing.assert_array_equal(d, depth_input(depth, 10.0))
    half_c, half_d, _ = network_inputs(color, depth, 0.5, 10.0)
    # Area averaging: each half-scale pixel is the mean of its 2x2 block.
    block = color[:2, :2].astype(np.float64).mean(axis=(0, 1)) - COLOR_MEAN_BGR
    np.testing.assert_allclose(half_c[:, 0, 0], block, atol=0.51)
    assert half_d.shape == (3, H // 2, W // 2)


# ----------------------------------------------------------------------------- post-processing


def _three_proposals() -> tuple[np.ndarray, np.ndarray]:
    boxes = np.array([[0.0, 0.0, 10.0, 10.0], [1.0, 0.0, 11.0, 10.0], [50.0, 50.0, 60.0, 60.0]])
    scores = np.zeros((3, NUM_CLASSES))
    chair, table = class_index("chair"), class_index("table")
    scores[:, chair] = [0.9, 0.8, 0.7]  # proposal 1 overlaps proposal 0 (IoU 9/11)
    scores[1, table] = 0.6  # same box as the suppressed chair, other class: kept
    return scores, boxes


def test_select_detections_known_answer() -> None:
    scores, boxes = _three_proposals()
    chair, table = class_index("chair"), class_index("table")
    rows, classes, kept = select_detections(scores, boxes, top_k=3, min_score=0.05, nms_iou=0.3)
    np.testing.assert_array_equal(rows, [0, 2, 1])
    np.testing.assert_array_equal(classes, [chair, chair, table])
    np.testing.assert_array_equal(kept, [0.9, 0.7, 0.6])
    # Top-k comes first: with k = 2 the chair's third proposal is never a candidate.
    rows, classes, _ = select_detections(scores, boxes, top_k=2, min_score=0.05, nms_iou=0.3)
    np.testing.assert_array_equal(rows, [0, 1])
    np.testing.assert_array_equal(classes, [chair, table])
    # The score threshold; a looser NMS keeps the overlapping chair.
    rows, classes, _ = select_detections(scores, boxes, top_k=3, min_score=0.65, nms_iou=0.9)
    np.testing.assert_array_equal(rows, [0, 1, 2])
    np.testing.assert_array_equal(classes, [chair] * 3)
    empty = select_detections(np.zeros((0, NUM_CLASSES)), np.zeros((0, 4)), 100, 0.0, 0.3)
    assert all(len(a) == 0 for a in empty)


def _random_outputs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    xy = rng.uniform(0, 200, (n, 2))
    boxes = np.hstack([xy, xy + rng.uniform(5, 60, (n, 2))])
    logits = rng.normal(0, 2, (n, NUM_OUTPUTS))
    probs = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    return probs[:, 1:], boxes


@pytest.mark.parametrize("top_k, min_score", [(100, 0.0), (7, 0.02)])
def test_select_detections_matches_greedy_per_class_nms(top_k: int, min_score: float) -> None:
    scores, boxes = _random_outputs(np.random.default_rng(top_k), 400)
    rows, classes, kept = select_detections(scores, boxes, top_k, min_score, 0.3)
    top = np.argsort(-scores, axis=0, kind="stable")[:top_k].T  # (C, k)
    cand_rows, cand_cls = top.ravel(), np.repeat(np.arange(NUM_CLASSES), top.shape[1])
    cand_scores = scores[cand_rows, cand_cls]
    ok = cand_scores >= min_score
    keep = batched_nms_2d(boxes[cand_rows[ok]], cand_scores[ok], cand_cls[ok], 0.3)
    np.testing.assert_array_equal(rows, cand_rows[ok][keep])
    np.testing.assert_array_equal(classes, cand_cls[ok][keep])
    np.testing.assert_array_equal(kept, cand_scores[ok][keep])
    assert (np.diff(kept) <= 0).all() and len(kept) > NUM_CLASSES


def test_decode_detections_known_deltas() -> None:
    n = 3
    centers = np.array([[9.0, 9.0, 9.0], [1.0, 0.5, 3.0], [-1.0, 0.2, 2.0]])
    sizes = np.tile([2.0, 1.0, 0.5], (NUM_CLASSES, 1))
    rng = np.random.default_rng(0)
    deltas3d = rng.normal(0, 1, (n, NUM_OUTPUTS, 7))  # noise everywhere but the selected rows/classes
    deltas2d = rng.normal(0, 1, (n, NUM_OUTPUTS, 4))
    chair, lamp = class_index("chair"), class_index("lamp")
    deltas3d[1, chair + 1] = [0.1, 0.2, -0.3, np.log(1.5), 0.0, np.log(2.0), 0.3]
    deltas3d[2, lamp + 1] = [0.0, 0.0, 0.0, 0.0, np.log(3.0), 0.0, 0.2]  # w 3 > l 2: made canonical
    proposals = np.array([[0.0, 0.0, 5.0, 5.0], [9.5, 19.5, 29.5, 59.5], [10.0, 10.0, 30.0, 20.0]])
    deltas2d[1, chair + 1] = [0.25, -0.1, np.log(2.0), np.log(0.5)]
    deltas2d[2, lamp + 1] = [0.0, 0.0, np.log(10.0), 0.0]  # 200 px wide: clipped to the image
    boxes3d, amodal = decode_detections(
        np.array([1, 2]), np.array([chair, lamp]), centers, sizes, proposals, deltas3d, deltas2d, (60, 100)
    )
    np.testing.assert_allclose(boxes3d[0], [1.2, 0.6, 2.7, 3.0, 1.0, 1.0, 0.3], atol=1e-12)
    np.testing.assert_allclose(
        boxes3d[1], [-1.0, 0.2, 2.0, 3.0, 2.0, 0.5, 0.2 + np.pi / 2 - np.pi], atol=1e-12
    )
    np.testing.assert_allclose(amodal[0], [4.5, 25.5, 44.5, 45.5], atol=1e-12)
    np.testing.assert_allclose(amodal[1], [-0.5, 10.0, 99.5, 20.0], atol=1e-12)
    empty3d, empty2d = decode_detections(np.zeros(0, int), np.zeros(0, int), centers, sizes, proposals,
                                         deltas3d, deltas2d, (60, 100))  # fmt: skip
    assert empty3d.shape == (0, 7) and empty2d.shape == (0, 4)


def test_proposal_config_round_trips_through_its_plain_form() -> None:
    config = ProposalConfig(max_proposals=123, min_area=50)
    plain = dataclasses.asdict(config)
    assert proposal_config_from_dict(plain) == config
    assert proposal_config_from_dict({}) == ProposalConfig()
    with pytest.raises(ValueError, match="unknown setting"):
        proposal_config_from_dict({**plain, "colour_bins": 3})


# ----------------------------------------------------------------------------- the pipeline


def test_pipeline_detections_round_trip_and_score(tmp_path: Path) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b", "c"], estimated_gravity=("c",))
    model = FakeModel()
    config = PipelineConfig.from_metadata(model.metadata)
    dets = [outcome.detections for outcome in detect_frames(FolderSource(folder), model, config)]
    for det in dets:
        n = len(det.scores)
        assert 0 < n <= NUM_CLASSES * 60
        assert det.boxes3d.shape == (n, 7) and det.boxes2d_amodal.shape == (n, 4)
        assert (det.boxes3d[:, 3] >= det.boxes3d[:, 4]).all() and (
            np.abs(det.boxes3d[:, 6]) <= np.pi / 2
        ).all()
        np.testing.assert_allclose(det.corners, box_corners_camera(det.boxes3d, det.R_tilt))
        assert set(det.timing) >= {
            "read",
            "depth_fill",
            "gravity",
            "proposals",
            "lifting",
            "network",
            "total",
        }
    assert model.calls == len(dets)  # one network call per frame
    np.testing.assert_allclose(dets[0].R_tilt, rtilt_from_pitch_roll(np.radians(-8.0), np.radians(1.5)))

    path = tmp_path / "detections.jsonl"
    write_detections(path, dets)
    back = read_detections(path)
    for det, line in zip(dets, back, strict=True):
        assert_same_detections(det, line, rounded=True)
        np.testing.assert_array_equal(line.scores, det.scores)
        np.testing.assert_array_equal(line.R_tilt, det.R_tilt)

    # Ground truth: each annotated frame's best detection and a made-up miss, so AP is neither 0 nor 1.
    truth = {}
    for det in dets[:2]:
        best = det.boxes3d[0]
        miss = best + np.array([5.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0])
        boxes2d = np.tile(det.boxes2d[:1], (2, 1))
        gt = GroundTruth.from_classes([det.classes[0]] * 2, np.vstack([best, miss]), boxes2d, boxes2d)
        color, depth = scene(ord(det.frame) - ord("a"))
        write_frame(folder, det.frame, color, depth, R_tilt=det.R_tilt, gt=gt)
        truth[det.frame] = FrameTruth(gt.class_ids, gt.boxes3d, det.R_tilt)
    in_memory = evaluate(truth, {d.frame: d for d in dets[:2]})
    from_file = evaluate(truth, {d.frame: d for d in back[:2]})
    assert 0.0 < in_memory.map_present(0.25) < 1.0
    assert from_file.map_present(0.25) == in_memory.map_present(0.25)
    assert eval_cli.main([str(folder), "--detections", str(path), "--out", str(tmp_path / "eval")]) == 0
    report = (tmp_path / "eval" / "eval.json").read_text()
    assert json.loads(report)["map"]["0.25"]["present_classes"] == pytest.approx(in_memory.map_present(0.25))


def test_overlapped_run_gives_the_sequential_results(tmp_path: Path) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b", "c"])
    model = FakeModel()
    config = PipelineConfig.from_metadata(model.metadata)
    sequential = list(detect_frames(FolderSource(folder), model, config))
    overlapped = list(detect_frames(FolderSource(folder), model, config, overlap=True))
    for a, b in zip(sequential, overlapped, strict=True):
        assert a.detections is not None and b.detections is not None
        assert_same_detections(a.detections, b.detections)


@pytest.mark.parametrize(
    ("front", "network", "threads", "pays"),
    [
        (0.15, 0.04, 2, True),  # a small model: the network hides behind the front end
        (0.13, 0.66, 2, False),  # the paper's VGG16 on 2 cores: overlap would double the network
        (0.15, 0.04, 1, False),  # one thread: nothing to overlap on
        (0.05, 0.10, 2, False),  # the network on 1 thread (0.2 s) would outlast sequential (0.16 s)
        (0.05, 0.10, 4, True),  # ... on 3 of 4 threads it would not
        (0.15, 0.001, 2, False),  # a negligible network: under 10 % to gain, not worth a thread
    ],
)
def test_overlap_pays_where_the_front_end_is_the_longer_part(
    front: float, network: float, threads: int, pays: bool
) -> None:
    timing = {"read": 0.2 * front, "proposals": 0.8 * front, "network": network, "postprocess": 0.01}
    assert overlap_pays(timing, threads) is pays


class TimedNetwork(FakeModel):
    def __init__(self, seconds: float) -> None:
        super().__init__()
        self.seconds = seconds

    def run(self, *args):
        time.sleep(self.seconds)
        return super().run(*args)


@pytest.mark.parametrize(("network", "front_end", "overlaps"), [(0.05, 0.2, True), (0.3, 0.0, False)])
def test_auto_overlap_times_a_frame_then_overlaps_only_where_it_pays(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, network: float, front_end: float, overlaps: bool
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b", "c", "d", "e"])
    model = TimedNetwork(network)
    config = PipelineConfig.from_metadata(model.metadata)
    sequential = list(detect_frames(FolderSource(folder), model, config))
    load_and_prepare = pipeline.load_and_prepare

    def slow_front_end(*args):
        prepared = load_and_prepare(*args)
        prepared.timing["proposals"] += front_end  # as if it took that long (the choice reads the timing)
        return prepared

    monkeypatch.setattr(pipeline, "load_and_prepare", slow_front_end)
    narrowed: list[int] = []

    def narrow(threads: int) -> FakeModel:
        narrowed.append(threads)
        return model

    auto = list(detect_frames_auto(FolderSource(folder), model, config, threads=2, narrow=narrow))
    # Frames a and b run sequentially (a warms up, b is timed); c is prepared after the choice.
    assert [o.overlapped for o in auto] == [False, False, False, overlaps, overlaps]
    assert narrowed == ([1] if overlaps else [])
    for a, b in zip(sequential, auto, strict=True):
        assert a.detections is not None and b.detections is not None
        assert_same_detections(a.detections, b.detections)


class CountedNetwork(TimedNetwork):
    def __init__(self, seconds: float) -> None:
        super().__init__(seconds)
        self.calls = 0

    def run(self, *args):
        self.calls += 1
        return super().run(*args)


def test_auto_overlap_goes_back_to_sequential_where_overlapped_frames_come_slower(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    names = [chr(ord("a") + i) for i in range(8)]
    folder = write_scene_folder(tmp_path / "frames", names)
    model, narrowed = CountedNetwork(0.05), CountedNetwork(0.4)  # the prediction says overlap; it is slower
    config = PipelineConfig.from_metadata(model.metadata)
    sequential = list(detect_frames(FolderSource(folder), FakeModel(), config))
    load_and_prepare = pipeline.load_and_prepare

    def slow_front_end(*args):
        prepared = load_and_prepare(*args)
        prepared.timing["proposals"] += 0.2  # as if it took that long: overlap_pays says yes
        return prepared

    monkeypatch.setattr(pipeline, "load_and_prepare", slow_front_end)

    def narrow(threads: int) -> CountedNetwork:
        cv2.setNumThreads(1)  # as a3d-run's: OpenCV leaves the cores to the network
        return narrowed

    monkeypatch.setattr(cv2, "getNumThreads", lambda: 2)  # the run's OpenCV threads before it narrows
    restored: list[int] = []
    monkeypatch.setattr(cv2, "setNumThreads", restored.append)
    auto = list(detect_frames_auto(FolderSource(folder), model, config, threads=2, narrow=narrow, probe=2))
    # a, b sequential (b timed); c prepared in the foreground and run on the full model while the
    # narrowed session is built; d and e overlapped and timed: slower, so f (prepared in the
    # background) runs on the full model and g, h sequentially.
    assert [o.overlapped for o in auto] == [False, False, False, True, True, True, False, False]
    assert narrowed.calls * 3 == model.calls > 0  # d, e on the narrowed model; a, b, c, f, g, h not
    assert "running sequentially from here" in caplog.text and restored == [1, 2]
    for a, b in zip(sequential, auto, strict=True):
        assert a.detections is not None and b.detections is not None
        assert_same_detections(a.detections, b.detections)


def test_precomputed_proposals_are_used_and_capped(tmp_path: Path) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    masks = np.zeros((5, H, W), bool)
    boxes = []
    for i in range(5):
        y, x = 4 + 8 * i, 3 + 12 * i
        masks[i, y : y + 20, x : x + 25] = True
        boxes.append([x - 0.5, y - 0.5, x + 24.5, y + 19.5])
    write_precomputed_proposals(folder / "a.proposals.npz", PrecomputedProposals.from_masks(boxes, masks))
    source = FolderSource(folder)
    ref_a, ref_b = source.refs
    model = FakeModel()

    def run(ref, **changes):
        config = PipelineConfig.from_metadata(model.metadata, **changes)
        return detect(source.read(ref), model, config)

    auto = run(ref_a)
    assert {tuple(b) for b in auto.boxes2d.tolist()} <= {tuple(b) for b in boxes}
    capped = run(ref_a, max_proposals=2)
    assert {tuple(b) for b in capped.boxes2d.tolist()} <= {tuple(b) for b in boxes[:2]}
    computed = run(ref_a, proposal_source="compute")
    assert not {tuple(b) for b in computed.boxes2d.tolist()} <= {tuple(b) for b in boxes}
    [outcome] = detect_frames([source.loader(ref_b)], model, PipelineConfig.from_metadata(model.metadata,
                              proposal_source="precomputed"))  # fmt: skip
    assert outcome.detections is None
    assert outcome.problem.startswith(str(ref_b.color_path)) and "no precomputed proposals" in outcome.problem


def test_the_detections_file_is_fsynced_after_its_first_line_then_at_most_once_a_second(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[int] = []
    now = [100.0]
    monkeypatch.setattr(run_cli.os, "fsync", synced.append)
    monkeypatch.setattr(run_cli.time, "monotonic", lambda: now[0])
    sink = run_cli._open_output(str(tmp_path / "d.jsonl"), append=False)
    sink.write("a")
    assert len(synced) == 1  # the first line at once
    now[0] += 0.5
    sink.write("b")
    assert len(synced) == 1  # not every frame waits on the disk
    now[0] += 0.6
    sink.write("c")
    assert len(synced) == 2
    sink.close()
    assert len(synced) == 3  # and at the end
    assert (tmp_path / "d.jsonl").read_text() == "a\nb\nc\n"
