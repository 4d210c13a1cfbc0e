"""bench/transfer.py and bench/false_positives.py end to end on tiny settings (few small frames,
two training iterations): the table holds every train -> test pair, its drops are what the
scores say, and the false positives are counted on exactly the frames without annotations."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import eval as eval_cli
from a3d.runtime.evaluation.metric import EvalConfig, FrameTruth, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.sources.folder import list_frames, read_ground_truth
from a3d.synth.cli import main as synth_main
from a3d.train.config import apply_overrides, load_config
from bench import background_rois, false_positives, transfer
from tests.helpers.samples import PINNED_DETECTIONS, PINNED_MODEL, SAMPLE_MODEL, SAMPLES
from tests.helpers.train_scenes import TINY

pytestmark = pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning")


def _empty_names(folder: Path) -> set[str]:
    return {r.name for r in list_frames(folder) if len(read_ground_truth(r)) == 0}


@pytest.mark.slow  # trains and runs the transfer benchmark end to end
def test_transfer_table_and_false_positives_end_to_end(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(transfer.WORLDS, "clutter", ["--clutter", "20", "--empty-share", "0.5"])
    sets = [f"--set={s}" for s in TINY if not s.startswith("log.")] + ["--set=log.progress=false"]
    argv = [
        "--out",
        str(tmp_path),
        "--worlds",
        "plain,clutter",
        "--frames",
        "6",
        "--test-share",
        "0.5",
        "--scale",
        "0.15",
        "--iters",
        "2",
        *sets,
    ]
    assert transfer.main(argv) == 0
    report = json.loads((tmp_path / "transfer.json").read_text())
    table = report["map25"]
    assert set(table) == {"plain", "clutter"} and all(set(row) == set(table) for row in table.values())
    for a, row in table.items():
        for b, value in row.items():
            assert 0.0 <= value <= 1.0
            assert value == report["scores"][f"{a}->{b}"]["map25_all"]
            if a != b:
                assert report["drop"][a][b] == pytest.approx(table[b][b] - value)
    # The plain world has no frame without annotations; the clutter world's test split has some,
    # and the false positives are counted on exactly those frames.
    assert report["false_positives"]["plain->plain"] is None
    clutter_test = tmp_path / "clutter" / "data" / "test"
    empty = _empty_names(clutter_test)
    assert empty
    for a in ("plain", "clutter"):
        fp = report["false_positives"][f"{a}->clutter"]
        dets = false_positives.by_frame(tmp_path / a / "on_clutter" / "detections.jsonl")
        expected = sum(int((dets[n].scores >= 0.5).sum()) for n in empty)
        assert fp["empty_frames"] == len(empty) and fp["detections"] == expected
        assert fp["per_frame"] == pytest.approx(expected / len(empty))


@pytest.mark.slow  # four a3d-run calls
def test_transfer_scores_given_models_on_given_test_folders(tmp_path: Path) -> None:
    """--model and --test: nothing rendered or trained; an ONNX model is scored through a3d-run
    with its own settings (the samples' score equals that of the pinned a3d-run output), the same
    model scores the same on every row, and a bad WORLD=PATH is refused in one line."""
    args = ["--frames", "2", "--seed", "3", "--world", "real", "--empty-share", "0.5", "--split", "test=1"]
    assert synth_main([str(tmp_path / "set"), *args, "--camera-scale", "0.25"]) == 0
    out = tmp_path / "out"
    given = [f"--model=plain={PINNED_MODEL}", f"--model=real={PINNED_MODEL}", f"--test=plain={SAMPLES}",
             f"--test=real={tmp_path / 'set' / 'test'}"]  # fmt: skip
    assert transfer.main(["--out", str(out), "--worlds", "plain,real", *given]) == 0
    assert not list(out.glob("*/data")) and not list(out.glob("*/run"))
    report = json.loads((out / "transfer.json").read_text())
    table = report["map25"]
    assert table["plain"] == table["real"] and report["drop"]["real"]["plain"] == 0.0
    truth, _ = eval_cli.load_truth(SAMPLES)
    pinned = false_positives.by_frame(PINNED_DETECTIONS)
    expected = evaluate(truth, pinned, EvalConfig()).map_all(0.25)
    assert table["plain"]["plain"] == pytest.approx(expected, abs=1e-9)
    assert report["false_positives"]["plain->real"]["empty_frames"] == 1
    with pytest.raises(SystemExit) as refused:
        transfer.main(["--out", str(out), "--worlds", "plain,real", "--model=kitchen=x.onnx"])
    assert refused.value.code == 2


def test_false_positives_runs_a3d_run_on_the_empty_frames(tmp_path: Path) -> None:
    """The bundled model on two small frames of rooms without class objects."""
    args = ["--frames", "2", "--seed", "3", "--world", "real", "--empty-share", "1", "--split", "test=1"]
    assert synth_main([str(tmp_path / "set"), *args, "--camera-scale", "0.25"]) == 0
    folder = tmp_path / "set" / "test"
    assert len(_empty_names(folder)) == 2
    assert (
        false_positives.main([str(folder), "--model", str(SAMPLE_MODEL), "--out", str(tmp_path / "d.jsonl")])
        == 0
    )
    report = json.loads((tmp_path / "d.report.json").read_text())
    dets = read_detections(tmp_path / "d.jsonl")
    assert report["empty_frames"] == 2
    assert report["detections"] == sum(int((d.scores >= 0.5).sum()) for d in dets)
    assert sum(report["by_class"].values()) == report["detections"]
    every = report["all_frames"]  # no object to get right in rooms without one
    assert every["frames"] == 2 and every["detections"] == report["detections"] and every["right"] == 0
    assert every["kinds"] == {"right_or_duplicate": 0, "same_class_poor_box": 0, "other_class_object": 0,
                              "no_labelled_object": report["detections"]}  # fmt: skip
    assert false_positives.main([str(folder), "--detections", str(tmp_path / "missing.jsonl")]) == 1


def test_right_share_counts_the_detections_the_evaluator_matched() -> None:
    """On the samples' pinned output: at threshold 0 every detection counts and the right ones are
    the true positives behind a3d-eval's recall; a higher threshold keeps fewer, a larger share right."""
    truth, _ = load_truth(SAMPLES)
    lines = false_positives.by_frame(PINNED_DETECTIONS)
    result = evaluate(truth, lines, EvalConfig(iou_thresholds=(0.25,)))
    everything = false_positives.right_share(SAMPLES, lines, 0.0)
    assert everything["detections"] == sum(c.num_det for c in result.classes)
    assert everything["right"] == round(
        sum(c.recall[0.25][-1] * c.num_gt for c in result.classes if c.num_det)
    )
    confident = false_positives.right_share(SAMPLES, lines, 0.5)
    assert 0 < confident["detections"] < everything["detections"]
    assert confident["share"] > everything["share"]
    for report in (everything, confident):  # every detection is of one kind; the right ones among the first
        assert sum(report["kinds"].values()) == report["detections"]
        assert report["kinds"]["right_or_duplicate"] >= report["right"]
    assert everything["kinds"]["same_class_poor_box"] > 0 and everything["kinds"]["no_labelled_object"] > 0


def test_each_detection_is_of_one_kind_by_its_best_3d_iou() -> None:
    chair, table = 4, 16
    truth = FrameTruth(
        np.array([chair, table]), np.array([[0, 0, 3, 1, 1, 1, 0], [3, 0, 3, 1, 1, 1, 0.0]]), np.eye(3)
    )
    cases = {
        (chair, (0.1, 0, 3)): "right_or_duplicate",  # IoU 0.82
        (chair, (0.8, 0, 3)): "same_class_poor_box",  # IoU 0.11
        (chair, (3, 0, 3)): "other_class_object",  # on the table
        (table, (0, 0, 6)): "no_labelled_object",  # 2 m behind both
    }
    for (c, centre), kind in cases.items():
        assert false_positives._kind(truth, c, np.array([*centre, 1, 1, 1, 0.0])) == kind, (c, centre)


def test_background_rois_at_bound_zero_keep_the_empty_rooms(tmp_path: Path) -> None:
    """At the default bound (0.1) a room without labelled objects offers no RoI and is skipped;
    at 0 it is kept with background RoIs only, and every frame offers at least as many."""
    args = "--frames 4 --seed 3 --empty-share 0.5 --clutter 20 --split test=0".split()
    assert synth_main([str(tmp_path / "set"), *args, "--size", "96x128"]) == 0
    folder = tmp_path / "set" / "train"
    empty = _empty_names(folder)
    assert len(empty) == 2
    config = apply_overrides(load_config("cpu-small"), list(TINY))
    report = background_rois.background_counts(folder, config, [0.1, 0.0], tmp_path / "cache")
    low, zero = report["0.1"], report["0.0"]
    assert low["frames_skipped"] >= len(empty) and zero["frames_kept"] == low["frames_kept"] + len(empty)
    assert zero["background_rois"] > low["background_rois"]
    assert zero["foreground_rois"] == low["foreground_rois"]
