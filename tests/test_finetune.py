"""a3d-finetune: the bundled model fine-tuned for a few iterations on a tiny posed sequence, end to
end (split, mix, read-back, training, int8 export, card), and a3d-run loads what it writes; bad
input is one line and exit 2 with nothing written."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from a3d.runtime.cli.common import EXIT_USAGE
from a3d.runtime.cli.run import main as run_main
from a3d.runtime.evaluation.metric import EvalConfig, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.sources.folder import (
    FolderSource,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.synth.cli import main as synth_main
from a3d.train import finetune_data
from a3d.train.checkpoint import load_checkpoint
from a3d.train.finetune import Recipe
from a3d.train.finetune_cli import main
from a3d.train.finetune_data import calibration_frames, read_recording, split_recordings

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 10-frame sequence of one room (a recording with its labels) and 4 synthetic frames to mix in."""
    root = tmp_path_factory.mktemp("finetune")
    assert synth_main([str(root / "seq"), "--sequence", "10", "--seed", "3", "--size", "120x160"]) == 0
    assert synth_main([str(root / "synth"), "--frames", "4", "--seed", "5", "--size", "120x160",
                       "--split", "test=0"]) == 0  # fmt: skip
    return root


@pytest.mark.slow
def test_a_fine_tune_of_seconds_end_to_end_writes_a_model_a3d_run_loads(
    data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "mine.onnx"
    argv = [str(data / "seq" / "frames"), "--out", str(out), "--minutes", "5", "--iters", "3",
            "--holdout", "0.3", "--synth", str(data / "synth" / "train"),
            "--set", "data.detector_rois=2"]  # fmt: skip
    assert main(argv) == 0
    said = capsys.readouterr().err
    metadata = DetectorModel.load(out, threads=1).metadata
    provenance = metadata.provenance
    card = provenance["finetune"]
    assert card["recipe"]["settings"] == ["data.detector_rois=2"]
    calib = provenance["export"]["calibration"]["folder"]  # the user's and the synthetic frames
    assert calib == str((tmp_path / "mine.finetune" / "calib").resolve())
    assert card["base"]["model"] == "real"  # the default pipeline: its network fine-tuned, its detector kept
    assert metadata.detector == card["base"]["detector"] == "yolox-nano"
    assert (card["data"]["train_frames"], card["data"]["holdout_frames"]) == (7, 3)
    assert card["data"]["objects_per_class"] and set(card["heldout_map25"]) == {
        "before", "before_present", "after", "after_present"}  # fmt: skip
    assert card["recipe"]["pooled_layout"] == "y, c, x" and not card["recipe"]["interrupted"]
    work = tmp_path / "mine.finetune"
    init, trained = (load_checkpoint(work / name)["model"] for name in ("init.pt", "run/checkpoint.pt"))
    config = load_checkpoint(work / "run" / "checkpoint.pt")["config"]  # trained as exported: no dropout
    assert card["recipe"]["dropout"] == 0 and json.loads(config)["net"]["dropout"] == 0
    assert card["recipe"]["freeze_depth"] == 10  # conv4_3 (features.21) kept, conv5_1 (features.24) learns
    assert torch.equal(init["depth_trunk.features.21.weight"], trained["depth_trunk.features.21.weight"])
    assert not torch.equal(init["depth_trunk.features.24.weight"], trained["depth_trunk.features.24.weight"])
    held = sorted(p.name for p in (tmp_path / "mine.finetune" / "holdout").glob("*.gt.json"))
    assert held == [f"r0_seq_{i:06d}.gt.json" for i in (7, 8, 9)]  # the recording's last stretch
    detections = tmp_path / "det.jsonl"
    frames = str(tmp_path / "mine.finetune" / "holdout")
    assert run_main([frames, "--model", str(out), "--output", str(detections), "--headless"]) == 0
    lines = [json.loads(line) for line in detections.read_text().splitlines()]
    assert len(lines) == 3  # and the model ran as the pipeline it names: the detector's lines carry sources
    assert all("source" in d for line in lines for d in line["detections"]) and lines[0]["detections"]
    truth, _ = load_truth(Path(frames))  # the card's pipeline numbers are what a3d-run gives there
    ran_lines = {d.frame: d for d in read_detections(detections)}
    ran = evaluate(truth, ran_lines, EvalConfig(iou_thresholds=(0.25,)))
    pipeline = card["heldout_map25_pipeline"]
    assert pipeline["detector"] == "yolox-nano"
    assert pipeline["after_present"] == pytest.approx(ran.map_present(0.25), abs=1e-9)
    assert pipeline["after"] == pytest.approx(ran.map_all(0.25), abs=1e-9)
    assert 0 <= pipeline["before_present"] <= 1 and 0 <= pipeline["before"] <= pipeline["before_present"]
    worse = pipeline["after_present"] < pipeline["before_present"]  # then the run said so
    assert ("the base model stays the better choice" in said) == worse
    alone = tmp_path / "alone.jsonl"
    argv = [frames, "--model", str(out), "--detector", "none", "--output", str(alone), "--headless"]
    assert run_main(argv) == 0
    alone_lines = [json.loads(line) for line in alone.read_text().splitlines()]
    assert not any("source" in d for line in alone_lines for d in line["detections"])


def _one_line_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str], expected: str) -> None:
    assert main(argv) == EXIT_USAGE
    lines = capsys.readouterr().err.strip().splitlines()  # progress lines before it, if any
    assert lines[-1].startswith("a3d-finetune: error: ") and expected in lines[-1], lines
    assert sum("error" in line for line in lines) == 1


def test_bad_input_is_one_line_and_nothing_is_written(
    data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "mine.onnx"
    unlabelled = tmp_path / "unlabelled"
    shutil.copytree(ROOT / "samples", unlabelled)
    for path in unlabelled.glob("*.gt.json"):
        path.unlink()
    _one_line_exit_2(
        [str(unlabelled), "--out", str(out)], capsys, f"{unlabelled}: 6 of 6 frames have no ground truth"
    )
    odd = tmp_path / "odd"
    shutil.copytree(data / "seq" / "frames", odd)
    truth = odd / "seq_000004.gt.json"
    document = json.loads(truth.read_text())
    document["objects"][0]["class"] = "robot"
    truth.write_text(json.dumps(document))
    _one_line_exit_2([str(odd), "--out", str(out)], capsys, "robot")
    synth = ["--synth", str(data / "synth" / "train")]
    _one_line_exit_2([str(data / "seq" / "frames"), "--out", str(out), "--minutes", "0.2", *synth], capsys,
                     "--minutes 0.2 is too short")  # fmt: skip
    assert not out.exists()


def test_the_recipe_counts_its_iterations_and_the_flags_take_it_over(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import a3d.train.finetune as finetune_module

    recipes = []
    monkeypatch.setattr(finetune_module, "finetune", lambda args, recipe: recipes.append(recipe) or args.out)
    out = str(tmp_path / "m.onnx")
    assert main([str(tmp_path), "--out", out]) == 0
    assert main([str(tmp_path), "--out", out, "--iters", "7", "--lr", "0.001"]) == 0
    assert recipes == [finetune_module.Recipe(), finetune_module.Recipe(lr=0.001, iterations=7)]
    # the budget alone no longer sets the count: a fast machine runs the same recipe as a slow one
    assert f"solver.iterations={recipes[0].iterations}" in recipes[0].overrides(tmp_path, 15.0, tmp_path)
    assert recipes[0].iterations < 10000  # the 13000 a bfloat16 CPU ran in 15 minutes lost (training.md)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        main([str(tmp_path), "--out", out, "--iters", "0"])
    assert stop.value.code == EXIT_USAGE and "--iters" in capsys.readouterr().err
    assert len(recipes) == 2


@pytest.mark.slow
def test_ctrl_c_stops_the_training_and_the_model_so_far_is_written(data: Path, tmp_path: Path) -> None:
    out = tmp_path / "stopped.onnx"
    argv = [sys.executable, "-m", "a3d.train.finetune_cli", str(data / "seq" / "frames"), "--out", str(out),
            "--minutes", "10", "--holdout", "0.3", "--synth", str(data / "synth" / "train")]  # fmt: skip
    run = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=ROOT)
    for line in run.stderr:  # the colour features are cached just before the first iteration
        if "colour trunk's features" in line:
            time.sleep(3)
            run.send_signal(signal.SIGINT)
            break
    rest = run.communicate(timeout=300)[1]
    assert run.returncode == 0, rest[-2000:]
    assert "interrupted: checkpoint of iteration" in rest
    assert DetectorModel.load(out, threads=1).metadata.provenance["finetune"]["recipe"]["interrupted"]


def test_the_int8_calibration_frames_spread_over_the_recordings_and_the_synthetic_ones(
    data: Path, tmp_path: Path
) -> None:
    own, synth = data / "seq" / "frames", data / "synth" / "train"
    calib = calibration_frames([own], synth, tmp_path, 6)
    refs = FolderSource(calib).refs  # each frame carries its own intrinsics: the folders' cameras differ
    assert len(refs) == 6
    sources = [(ref.color_path.resolve().parent, ref.color_path.resolve().name) for ref in refs]
    own_names = [p.name for p in sorted(own.glob("*.color.png"))]
    synth_names = [p.name for p in sorted(synth.glob("*.color.png"))]
    assert sources[:3] == [(own.resolve(), own_names[i]) for i in (0, 3, 6)]  # spread, not the first three
    assert sources[3:] == [(synth.resolve(), synth_names[i]) for i in (0, 1, 2)]
    assert all(read_frame(ref, None).intrinsics is not None for ref in refs)


def test_frames_larger_than_the_working_size_are_fine_tuned_on_at_it(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seq = data / "seq" / "frames"
    recording = read_recording(seq)
    linked = split_recordings([recording], 0.3, tmp_path / "as_is")
    assert all(p.is_symlink() for p in linked.train[0].glob("*.color.png"))  # 120 x 160: as they are
    monkeypatch.setattr(finetune_data, "WORKING_SIDE", 80)  # a3d-run's 640, scaled to the test's frames
    split = split_recordings([recording], 0.3, tmp_path / "small")
    source = FolderSource(split.train[0], with_truth=True)
    assert len(source.refs) == 7 and not any(ref.color_path.is_symlink() for ref in source.refs)
    for ref, original in zip(source.refs, recording.refs[:7], strict=True):
        small, big = source.read(ref), read_frame(original, read_folder_intrinsics(seq))
        big_truth = read_ground_truth(original)
        assert small.image_size == (60, 80) and small.R_tilt is not None
        assert small.intrinsics == big.intrinsics.resized(0.5, 0.5)
        np.testing.assert_allclose(small.truth.boxes3d, big_truth.boxes3d)  # metric: unchanged
        np.testing.assert_allclose(small.truth.boxes2d_visible, (big_truth.boxes2d_visible + 0.5) / 2 - 0.5)
        instances = read_instances(ref)
        for box, instance in zip(small.truth.boxes2d_visible, small.truth.instance_ids, strict=True):
            rows, cols = np.nonzero(instances == instance)  # its pixels at the new size lie in its box
            assert len(rows) and cols.min() >= box[0] - 1 and cols.max() <= box[2] + 1
            assert rows.min() >= box[1] - 1 and rows.max() <= box[3] + 1
    held = FolderSource(split.holdout).refs
    assert all(read_frame(ref, None).image_size == (60, 80) for ref in held)


def test_a_small_recording_is_mixed_with_no_fewer_than_the_recipes_synthetic_frames() -> None:
    recipe = Recipe()
    assert recipe.synth_frames(None, 3) == recipe.min_synth_frames == 40  # three views: forty frames
    assert recipe.synth_frames(None, 120) == 120  # a recording: as many as its training frames
    assert recipe.synth_frames(7, 3) == 7  # --synth-frames as asked
