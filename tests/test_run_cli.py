"""a3d-run end to end: exit codes, bad frames, --resume, --output -, the rerun recording, a real model.

Most tests substitute the fake model of tests/test_run.py for the model loader; the last one
exports a tiny network with a3d.export and runs the command on it as a user would.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.sources.folder import FolderSource, write_frame
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from tests.helpers.runtime_frames import (
    FakeModel,
    H,
    K,
    W,
    assert_same_detections,
    fake_metadata,
    scene,
    write_scene_folder,
)
from tests.rrd_reader import as_array, read_columns


def run(argv: list[str]) -> int:
    """main's exit status, whether it returns it or argparse raises SystemExit."""
    try:
        return run_cli.main(argv)
    except SystemExit as e:
        return int(e.code or 0)


@pytest.fixture
def fake_model(monkeypatch: pytest.MonkeyPatch) -> FakeModel:
    model = FakeModel()
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: model)
    return model


def lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_help_exits_zero(capsys: pytest.CaptureFixture) -> None:
    assert run(["--help"]) == 0
    out = capsys.readouterr().out
    for flag in ("--model", "--output", "--resume", "--proposals", "--max-proposals", "--save", "--headless"):
        assert flag in out


def test_usage_errors_exit_2_before_any_frame(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    out = tmp_path / "det.jsonl"
    missing = tmp_path / "none.onnx"  # (no --model and no FOLDER/model.onnx: the bundled default runs)
    assert run([str(folder), "--model", str(missing), "--output", str(out), "--headless"]) == 2
    err = capsys.readouterr().err  # one line, without the usage: the flags were right
    assert err == f"a3d-run: error: {missing}: no such model file\n"
    (folder / "model.onnx").write_bytes(b"\x08\x07 this is not an onnx file")
    assert run([str(folder), "--output", str(out), "--headless"]) == 2  # the real loader refuses it
    err = capsys.readouterr().err
    assert err.startswith("a3d-run: error: ") and "model.onnx" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert run([str(folder), "--threads", "0", "--headless"]) == 2
    assert run([str(folder), "--proposals", "mcg", "--headless"]) == 2
    capsys.readouterr()
    assert run([str(folder), "--working-side", "-1", "--headless"]) == 2
    assert "--working-side must be 0" in capsys.readouterr().err
    assert run([str(tmp_path / "nowhere"), "--model", str(folder / "model.onnx"), "--headless"]) == 2
    capsys.readouterr()
    assert run([str(tmp_path / "nowhere"), "--headless"]) == 2  # the folder is named, not the model
    assert capsys.readouterr().err == f"a3d-run: error: {tmp_path / 'nowhere'}: no such file or folder\n"
    assert not out.exists()


def _mixed_folder(folder: Path) -> dict[str, str]:
    """Three good frames (per-frame intrinsics, no intrinsics.json; one with estimated gravity)
    and three bad ones; returns {bad frame: the file its error must name}."""
    folder.mkdir()
    for i, name in enumerate(["g1", "g2", "g3"]):
        color, depth = scene(i)
        R = None if name == "g2" else rtilt_from_pitch_roll(np.radians(-10.0), 0.0)
        write_frame(folder, name, color, depth, R_tilt=R, intrinsics_override=K)
    color, depth = scene(5)
    write_frame(folder, "truncated", color, depth, intrinsics_override=K)
    data = (folder / "truncated.color.png").read_bytes()
    (folder / "truncated.color.png").write_bytes(data[: len(data) // 2])
    write_frame(folder, "other_size", color, depth, intrinsics_override=K)
    cv2.imwrite(str(folder / "other_size.depth.png"), np.full((H - 8, W), 2000, np.uint16))
    write_frame(folder, "no_intrinsics", color, depth, R_tilt=np.eye(3))
    return {
        "truncated": "truncated.color.png",
        "other_size": "other_size.depth.png",
        "no_intrinsics": "intrinsics.json",
    }


def test_bad_frames_are_reported_and_the_rest_match_a_clean_run(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    folder = tmp_path / "frames"
    bad = _mixed_folder(folder)
    mixed = tmp_path / "mixed.jsonl"  # bad frames fail on the background thread too
    argv = [str(folder), "--model", "m.onnx", "--output", str(mixed), "--headless", "--overlap", "on"]
    assert run(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    reports = ("a3d-run: 3 frames written", "a3d-run: summary: ", "a3d-run: progress: ", "a3d-run: warning: ")
    problems = [line for line in err.splitlines() if not line.startswith(reports)]
    assert len(problems) == len(bad)
    for name, file in bad.items():
        [line] = [p for p in problems if f"/{file}" in p and name in p]
        assert line.startswith(f"a3d-run: {folder}")

    for name in bad:
        for path in folder.glob(f"{name}.*"):
            path.unlink()
    clean = tmp_path / "clean.jsonl"
    assert run([str(folder), "--model", "m.onnx", "--output", str(clean), "--headless"]) == 0
    got, want = read_detections(mixed), read_detections(clean)
    assert [d.frame for d in got] == ["g1", "g2", "g3"]
    for a, b in zip(got, want, strict=True):
        assert_same_detections(a, b)
        assert (a.color, a.depth) == (b.color, b.depth)
        assert len(a.scores) > 0


def test_frame_without_depth_gives_an_empty_line_and_a_warning(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    color, depth = scene(1)
    write_frame(folder, "z", color, np.zeros_like(depth))
    out = tmp_path / "det.jsonl"
    assert run([str(folder), "--model", "m.onnx", "--output", str(out), "--headless"]) == 0
    a, z = read_detections(out)
    assert len(a.scores) > 0 and len(z.scores) == 0
    no_depth, gravity = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert no_depth.startswith("a3d-run: warning: ") and "z.depth.png" in no_depth
    assert (
        gravity.startswith("a3d-run: warning: ")
        and "/z." in gravity
        and "gravity fallback: camera axes" in gravity
    )


def test_resume_after_a_crash_gives_the_clean_file(tmp_path: Path, fake_model: FakeModel) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b", "c", "d"])
    clean = tmp_path / "clean.jsonl"
    assert run([str(folder), "--model", "m.onnx", "--output", str(clean), "--headless"]) == 0
    full = lines(clean)
    assert len(full) == 4

    out = tmp_path / "resumed.jsonl"
    out.write_text(full[0] + "\n" + full[1] + "\n" + full[2][: len(full[2]) // 2])  # killed mid-line
    calls = fake_model.calls
    assert run([str(folder), "--model", "m.onnx", "--output", str(out), "--resume", "--headless"]) == 0
    assert fake_model.calls - calls == 2  # only c and d were run again
    resumed = lines(out)
    assert resumed[:2] == full[:2]  # kept byte for byte
    for a, b in zip(read_detections(out), read_detections(clean), strict=True):
        assert_same_detections(a, b)

    # Nothing left to do; a file that is not a detections file is refused, not appended to.
    assert run([str(folder), "--model", "m.onnx", "--output", str(out), "--resume", "--headless"]) == 0
    assert lines(out) == resumed
    bogus = tmp_path / "bogus.jsonl"
    bogus.write_text('{"something": "else"}\n')
    assert run([str(folder), "--model", "m.onnx", "--output", str(bogus), "--resume", "--headless"]) == 2
    assert lines(bogus) == ['{"something": "else"}']


def test_output_to_stdout_keeps_stdout_for_data(
    tmp_path: Path, fake_model: FakeModel, capsys: pytest.CaptureFixture
) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    assert run([str(folder), "--model", "m.onnx", "--output", "-", "--headless"]) == 0
    captured = capsys.readouterr()
    records = [json.loads(line) for line in captured.out.splitlines()]
    assert [r["frame"] for r in records] == ["a", "b"]
    first = records[0]["detections"][0]
    assert set(first) == {"class", "score", "box2d", "box2d_amodal", "box3d", "corners"}
    assert {"read", "proposals", "network", "postprocess", "total"} <= set(records[0]["timing"])
    assert "{" not in captured.err


def test_saved_recording_holds_the_written_boxes(tmp_path: Path, fake_model: FakeModel) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    color, depth = scene(0)
    R = rtilt_from_pitch_roll(np.radians(-8.0), np.radians(1.5))
    gt = GroundTruth.from_classes(
        ["sofa"], [[0.2, 0.5, 3.0, 2.0, 0.9, 0.8, 0.3]], [[1, 2, 30, 40]], [[1, 2, 30, 40]]
    )
    write_frame(folder, "a", color, depth, R_tilt=R, gt=gt)
    out, rrd = tmp_path / "det.jsonl", tmp_path / "run.rrd"
    assert (
        run(
            [
                *(str(folder), "--model", "m.onnx", "--output", str(out), "--headless", "--save", str(rrd)),
                *("--view-min-score", "0"),  # draw every detection, so the view holds all written boxes
            ]
        )
        == 0
    )

    logged = read_columns(rrd, "/world/detections")
    assert sorted(logged) == [0, 1]
    for index, det in enumerate(read_detections(out)):
        boxes = logged[index]
        np.testing.assert_allclose(
            as_array(boxes["Boxes3D:centers"]), det.boxes3d[:, :3] @ det.R_tilt.T, atol=1e-5
        )
        np.testing.assert_allclose(
            as_array(boxes["Boxes3D:half_sizes"]), det.boxes3d[:, [3, 5, 4]] / 2, atol=1e-5
        )
        angles = [r["angle"] for r in boxes["Boxes3D:rotation_axis_angles"]]
        np.testing.assert_allclose(angles, det.boxes3d[:, 6], atol=1e-5)
        assert boxes["Boxes3D:class_ids"] == (det.class_ids + 1).tolist()
    truth = read_columns(rrd, "/world/ground_truth")
    assert sorted(truth) == [0]
    np.testing.assert_allclose(as_array(truth[0]["Boxes3D:centers"]), gt.boxes3d[:, :3] @ R.T, atol=1e-5)


def test_headless_without_a_sink_records_nothing(tmp_path: Path, fake_model: FakeModel, monkeypatch) -> None:
    folder = write_scene_folder(tmp_path / "frames", ["a"])
    monkeypatch.setattr(run_cli.viewer, "load_view", lambda: pytest.fail("rerun view loaded"))
    assert run([str(folder), "--model", "m.onnx", "--output", str(tmp_path / "d.jsonl"), "--headless"]) == 0


@pytest.mark.slow  # the ONNX export takes ~10-30 s
def test_exported_model_end_to_end(tmp_path: Path) -> None:
    """A tiny exported network through the command; the ONNX scores match the eager network's."""
    pytest.importorskip("torch")
    import torch

    from a3d.export.onnx_export import RuntimeGraph, export_graph, save_model
    from a3d.runtime.pipeline import PipelineConfig, detect
    from a3d.train.dataset import TargetStats
    from a3d.train.inference import TorchNetwork
    from a3d.train.model import A3DNet, NetConfig

    torch.manual_seed(0)
    net = A3DNet(NetConfig(width=0.125, fc6=32, fc7=32, dropout=0.0)).eval()
    stats = TargetStats.identity()
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"], estimated_gravity=("b",))
    raw = export_graph(RuntimeGraph(net, stats), tmp_path / "raw.onnx")
    save_model(raw, fake_metadata(), folder / "model.onnx")

    out = tmp_path / "det.jsonl"
    assert run([str(folder), "--output", str(out), "--headless", "--threads", "1"]) == 0
    got = read_detections(out)
    assert [d.frame for d in got] == ["a", "b"]

    eager = TorchNetwork(net, stats)
    config = PipelineConfig.from_metadata(fake_metadata())
    source = FolderSource(folder)
    for det, ref in zip(got, source.refs, strict=True):
        reference = detect(source.read(ref), eager, config)
        assert len(det.scores) > 0
        # The best score per class is continuous in the network outputs (no ties to flip).
        for c in np.unique(reference.class_ids):
            assert det.scores[det.class_ids == c].max() == pytest.approx(
                reference.scores[reference.class_ids == c].max(), abs=1e-4
            )


def test_the_view_threshold_help_says_what_the_threshold_means() -> None:
    """--view-min-score's help states the calibrated meaning of 0.5, not measured shares (docs/live.md)."""
    from a3d.runtime.postprocess.score_calibration import SHOW_THRESHOLD

    (action,) = [a for a in run_cli.build_parser()._actions if "--view-min-score" in a.option_strings]
    assert action.default == SHOW_THRESHOLD == 0.5
    assert "as likely right as wrong" in action.help
    assert not re.search(r"half|most|\d+ ?%|0\.\d\d", action.help), action.help
