"""TUM RGB-D sequences: association, intrinsics presets, units, and a3d-run on one equals a3d-run
on the same frames as an a3d frame folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from a3d.runtime import Detector
from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.sources.overrides import INTRINSICS_PRESETS, parse_intrinsics
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.sources.tum import TumSource, associate
from tests.real_formats import assert_same_detections, run_detections, synth_frames, write_tum

STAMPS = [1305031102.175304, 1305031102.211214]


def test_association_pairs_the_closest_first_and_uses_each_stamp_once() -> None:
    colour = [1.000, 1.033, 1.066, 2.000]
    depth = [1.010, 1.030, 1.050, 1.500]
    # 1.033-1.030 (3 ms) goes first; 1.000 takes 1.010; 1.066 is 16 ms from 1.050, within 20 ms;
    # 2.000 has nothing within 20 ms and 1.500 is left over.
    assert associate(colour, depth, 0.02) == [(0, 0), (1, 1), (2, 2)]
    assert associate(colour, depth, 0.012) == [(0, 0), (1, 1)]
    assert associate([1.0], [1.0 + 0.02], 0.02) == []  # strictly within the tolerance


def test_sequence_reads_frames_in_metres_with_timestamps(tmp_path: Path, caplog) -> None:
    frames = synth_frames()
    folder = tmp_path / "rgbd_dataset_freiburg2_desk"
    depths = write_tum(folder, frames, STAMPS)
    with (folder / "rgb.txt").open("a") as f:
        f.write("1305031109.000000 rgb/lonely.png\nnot a line\n")
    source = open_source(folder, SourceOptions())
    assert isinstance(source, TumSource) and len(source) == 2
    assert source.incomplete == [f"{folder / 'rgb.txt'}:6: expected 'timestamp path', got 'not a line'"]
    with caplog.at_level("WARNING"):
        loaded = [loader.load() for loader in source]
    assert "1 colour image(s) without depth within 0.02 s skipped (0 depth image(s) unused)" in caplog.text
    for frame, synth, depth, t in zip(loaded, frames, depths, STAMPS, strict=True):
        assert frame.name == f"{t:.6f}" and frame.timestamp == pytest.approx(t, abs=1e-6)
        assert frame.intrinsics == INTRINSICS_PRESETS["fr2"]  # from the folder's name
        np.testing.assert_array_equal(frame.color, synth.color)
        np.testing.assert_array_equal(frame.depth, depth)
        assert np.abs(frame.depth - synth.depth).max() <= 0.5 / 5000  # 5000 units per metre
        assert frame.R_tilt is None and frame.depth_file.endswith(".png")


def test_intrinsics_are_required_unless_the_name_says_the_camera(tmp_path: Path) -> None:
    write_tum(tmp_path / "my_sequence", synth_frames((3,)), STAMPS[:1])
    with pytest.raises(InputError, match=r"my_sequence: not named rgbd_dataset_freiburgN_.*") as caught:
        open_source(tmp_path / "my_sequence")
    assert "pass intrinsics=(fx, fy, cx, cy)" in str(caught.value) and "--" not in str(caught.value)
    given = parse_intrinsics("100,101,60.5,45")
    frame = next(iter(open_source(tmp_path / "my_sequence", SourceOptions(intrinsics=given)))).load()
    assert frame.intrinsics == given
    # The same forms as Detector.detect takes, as keywords: a 4-tuple or a 3x3 K.
    for form in ((100.0, 101.0, 60.5, 45.0), given.matrix()):
        frame = next(iter(open_source(tmp_path / "my_sequence", intrinsics=form))).load()
        assert frame.intrinsics == given
    assert parse_intrinsics("freiburg3") == INTRINSICS_PRESETS["fr3"]
    for bad in ("100,101,60", "fr4", "1,x,2,3", "-5,5,1,1"):
        with pytest.raises(InputError, match="--intrinsics"):
            parse_intrinsics(bad)


def test_depth_scale_override_replaces_the_unit(tmp_path: Path) -> None:
    folder = tmp_path / "rgbd_dataset_freiburg1_xyz"
    write_tum(folder, synth_frames((3,)), STAMPS[:1])
    plain = next(iter(open_source(folder, SourceOptions()))).load()
    halved = next(iter(open_source(folder, SourceOptions(depth_scale=0.0001)))).load()
    np.testing.assert_array_equal(halved.depth * np.float32(2), plain.depth)  # units / 10000 vs / 5000


def test_run_on_a_sequence_equals_run_on_the_frame_folder(tmp_path: Path, tiny_model: Path) -> None:
    frames = synth_frames()
    sequence = tmp_path / "rgbd_dataset_freiburg1_desk"
    depths = write_tum(sequence, frames, STAMPS)
    folder = tmp_path / "frames"
    for frame, depth, t in zip(frames, depths, STAMPS, strict=True):
        write_frame(folder, f"{t:.6f}", frame.color, depth, depth_format="npy")
    write_intrinsics(folder, INTRINSICS_PRESETS["fr1"])
    expected = run_detections(folder, tiny_model, tmp_path / "folder.jsonl")
    assert_same_detections(run_detections(sequence, tiny_model, tmp_path / "tum.jsonl"), expected)
    # The Python API on the same source (docs/sources.md), to the detections file's precision.
    detector = Detector.load(tiny_model, threads=1)
    outcomes = detector.detect_frames(open_source(sequence, SourceOptions()), score_threshold=0)
    assert_same_detections({o.name: o.detections for o in outcomes}, expected, atol=1e-4)
    # The same with the camera given on the command line, and split into two shards.
    K = frames[0].intrinsics
    write_intrinsics(folder, K)
    expected = run_detections(folder, tiny_model, tmp_path / "folder2.jsonl")
    given = ("--intrinsics", f"{K.fx!r},{K.fy!r},{K.cx!r},{K.cy!r}")
    shards = {}
    for k in (0, 1):
        shard = run_detections(
            sequence, tiny_model, tmp_path / f"shard{k}.jsonl", *given, "--shard", f"{k}/2"
        )
        assert list(shard) == [f"{STAMPS[k]:.6f}"]
        shards.update(shard)
    assert_same_detections(shards, expected)


def test_the_command_line_names_its_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The error Python gets in keywords, a3d-run gets in flags: the same source, the same problem."""
    write_tum(tmp_path / "my_sequence", synth_frames((3,)), STAMPS[:1])
    argv = [str(tmp_path / "my_sequence"), "--model", str(tmp_path / "m.onnx"), "--headless"]
    assert run_cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.endswith("pass --intrinsics fx,fy,cx,cy or --intrinsics fr1|fr2|fr3\n") and "=(" not in err
