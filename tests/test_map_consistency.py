"""The label-free consistency measures of an object map (re-detection, jitter, spurious rate), the
map against world boxes, and bench.map_consistency end to end."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.mapping.consistency import against_world, map_consistency
from a3d.runtime.mapping.object_map import ObjectMap
from a3d.runtime.mapping.world_boxes import WorldBoxes
from a3d.runtime.structures.classes import class_index
from a3d.synth.cli import main as synth_main
from bench.map_consistency import main as bench_main
from tests.helpers.runtime_frames import FakeModel
from tests.test_object_map import CLASSES, SIZE, WORLD, K, camera, detections, noisy


def noisy_map(frames: int, ghost: bool = False) -> ObjectMap:
    rng = np.random.default_rng(1)
    world_map = ObjectMap()
    for i in range(frames):
        boxes, classes, scores = noisy(rng, WORLD), CLASSES, [0.9, 0.8]
        if ghost and i == 0:
            boxes = np.vstack([boxes, [[-0.5, -0.4, 2.5, 0.4, 0.4, 0.8, 0.0]]])
            classes, scores = [*CLASSES, class_index("lamp")], [0.9, 0.8, 0.6]
        world_map.update(detections(i, camera(i), boxes, classes, scores), intrinsics=K, image_size=SIZE)
    return world_map


def test_jitter_measures_the_noise_of_the_observations() -> None:
    measures = map_consistency(noisy_map(40), min_support=3)
    assert [o.cls for o in measures.objects] == ["chair", "bed"]
    for o in measures.objects:
        assert o.support == o.expected == 40 and o.redetection == 1.0
        assert 0.04 < o.centre_jitter_m < 0.065  # 3 cm per axis: sqrt(3) x 3 cm = 5.2 cm
        assert 0.035 < o.size_jitter < 0.065  # 5 % per size
        assert 1.5 < o.yaw_jitter_deg < 4.5  # 0.05 rad = 2.9 degrees (the bed's 40 draws: 2.0)
    assert measures.spurious == 0 and measures.median("redetection") == 1.0


def test_a_spurious_detection_counts_and_misses_lower_the_redetection_rate() -> None:
    world_map = noisy_map(8, ghost=True)
    measures = map_consistency(world_map, min_support=3)
    assert measures.detections == 17 and measures.spurious == 1  # the lamp seen once, then dropped
    assert measures.spurious_rate == pytest.approx(1 / 17)
    world_map.update(detections(8, camera(8), WORLD[:1], CLASSES[:1], [0.9]), intrinsics=K, image_size=SIZE)
    bed = next(o for o in map_consistency(world_map, 3).objects if o.cls == "bed")
    assert bed.expected == 9 and bed.redetection == pytest.approx(8 / 9)


def test_the_map_against_world_boxes() -> None:
    world_map = noisy_map(6)
    unseen = [[3.0, -0.4, 5.0, 0.5, 0.5, 0.8, 0.0]]
    world = WorldBoxes(["chair", "bed", "lamp"], np.vstack([WORLD, unseen]), np.array([1, 2, 3]))
    accuracy = against_world(world_map, world, min_support=3)
    assert (accuracy.objects, accuracy.true, accuracy.world) == (2, 2, 3)
    assert accuracy.precision == 1.0 and accuracy.recall == pytest.approx(2 / 3)
    assert max(accuracy.centre_errors_m) < 0.05
    assert len(accuracy.size_errors) == 2 and max(accuracy.size_errors) < 0.05  # 5 % noise, fused
    assert against_world(world_map, world, 3, seen={1, 2}).recall == 1.0
    assert against_world(world_map, world, min_support=7).objects == 0  # nothing seen 7 times


def test_bench_map_consistency_runs_on_a3d_run_output(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: FakeModel())
    assert synth_main([str(tmp_path / "seq"), "--sequence", "6", "--seed", "3", "--size", "96x128"]) == 0
    frames, out = tmp_path / "seq" / "frames", tmp_path / "det.jsonl"
    argv = [
        str(frames),
        "--model",
        "fake.onnx",
        "--output",
        str(out),
        "--headless",
        "--score-threshold",
        "0.0",
    ]
    assert run_cli.main(argv) == 0
    capsys.readouterr()
    world = str(tmp_path / "seq" / "world_boxes.json")
    report_path = tmp_path / "report.json"
    assert (
        bench_main(
            [str(frames), "--detections", str(out), "--world-boxes", world, "--json", str(report_path)]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert (
        "frames mapped: 6" in printed and "labelled: mAP@0.25" in printed and "map objects right" in printed
    )
    report = json.loads(report_path.read_text())
    assert report["frames_mapped"] == 6 and 0.0 <= report["spurious_rate"] <= 1.0
    assert {"map_precision", "map_recall", "map_at_025_present"} <= set(report)
