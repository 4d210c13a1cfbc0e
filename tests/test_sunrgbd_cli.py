"""a3d-sunrgbd on a small tree in each layout: frames, ground truth, R_tilt, the official split,
both class mappings, and bad files named in one line each (exit 1)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli.eval import main as eval_main
from a3d.runtime.cli.sunrgbd import main
from a3d.runtime.evaluation.protocols import SUNRGBD
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.sources.folder import FolderSource, list_frames
from a3d.runtime.sources.sunrgbd_conventions import map_class
from a3d.runtime.structures.geometry import canonical_boxes
from a3d.synth import SynthFrame
from tests.real_formats import (
    A,
    R_y,
    footprints_of,
    jpeg,
    labels_of,
    sun_intrinsics,
    sun_name,
    synth_frames,
    upright_cloud,
    write_sun_release_frame,
    write_votenet_frame,
)


def read_out(folder: Path) -> dict[str, object]:
    source = FolderSource(folder, with_truth=True)
    return {loader.name: loader.load() for loader in source}


def check_frame(frame, synth: SynthFrame, classes: str, atol: float) -> None:
    keep = [i for i, c in enumerate(synth.gt.classes) if map_class(sun_name(c), classes)]
    assert frame.truth.classes == [synth.gt.classes[i] for i in keep]
    np.testing.assert_allclose(frame.truth.boxes3d, canonical_boxes(synth.gt.boxes3d[keep]), atol=atol)
    np.testing.assert_allclose(frame.R_tilt, synth.R_tilt, atol=1e-12)
    assert frame.intrinsics == sun_intrinsics(synth)


@pytest.mark.parametrize("classes", ["nyu19", "sun10"])
def test_release_tree_with_its_split(tmp_path: Path, classes: str, capsys: pytest.CaptureFixture) -> None:
    scipy_io = pytest.importorskip("scipy.io")
    frames = synth_frames((3, 4, 5))
    root = tmp_path / "SUNRGBD"
    folders = [
        root / "kv1" / "NYUdata" / "NYU0001",
        root / "kv1" / "NYUdata" / "NYU0002",
        root / "kv2" / "align" / "x",
    ]
    colours = []
    for folder, frame in zip(folders, frames, strict=True):
        E = R_y(0.3) @ frame.R_tilt
        colours.append(jpeg(frame.color))
        write_sun_release_frame(
            folder, colours[-1], np.rint(frame.depth * 1000), frame.intrinsics, E, footprints_of(frame, E)
        )
    (folders[2] / "depth" / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    split = tmp_path / "SUNRGBDtoolbox" / "traintestSUNRGBD" / "allsplit.mat"
    split.parent.mkdir(parents=True)
    cells = {
        "alltrain": np.array(
            ["/n/fs/sun3d/data/SUNRGBD/kv1/NYUdata/NYU0001", "/n/fs/sun3d/data/SUNRGBD/kv2/align/x"],
            dtype=object,
        ),
        "alltest": np.array(["/n/fs/sun3d/data/SUNRGBD/kv1/NYUdata/NYU0002/"], dtype=object),
    }
    scipy_io.savemat(split, cells)
    out = tmp_path / "out"
    assert main([str(root), str(out), "--classes", classes]) == 1  # one frame failed
    err = capsys.readouterr().err.splitlines()
    bad = [line for line in err if line.startswith("a3d-sunrgbd: ") and "x.png" in line]
    assert len(bad) == 1 and str(folders[2] / "depth" / "x.png") in bad[0]
    assert sorted(p.name for p in out.iterdir()) == ["train", "val"]
    train, val = read_out(out / "train"), read_out(out / "val")
    assert list(train) == ["kv1__NYUdata__NYU0001"] and list(val) == ["kv1__NYUdata__NYU0002"]
    for frame, synth in (
        (train["kv1__NYUdata__NYU0001"], frames[0]),
        (val["kv1__NYUdata__NYU0002"], frames[1]),
    ):
        check_frame(frame, synth, classes, atol=1e-9)
        np.testing.assert_array_equal(
            frame.depth, np.rint(synth.depth * 1000).astype(np.float32) / np.float32(1000)
        )
    assert list_frames(out / "train")[0].color_path.read_bytes() == colours[0]  # the JPEG copied unchanged


def test_votenet_tree_with_its_split(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    frames = synth_frames((3, 4, 5))
    root = tmp_path / "sunrgbd_trainval"
    for k, frame in enumerate(frames, start=1):
        Rtilt_sun = A @ (R_y(-0.5) @ frame.R_tilt) @ A.T
        cloud = upright_cloud(frame.depth, frame.color, frame.intrinsics, Rtilt_sun)
        write_votenet_frame(
            root, k, jpeg(frame.color), cloud, Rtilt_sun, frame.intrinsics, labels_of(frame, Rtilt_sun)
        )
    (root / "label" / "000003.txt").write_text("chair 1 2 3\n")
    (root / "image" / "000004.jpg").write_bytes(jpeg(frames[0].color))  # no depth/, no calib/
    (root / "train_data_idx.txt").write_text("1\n3\n")
    (root / "val_data_idx.txt").write_text("2\n")
    out = tmp_path / "out"
    assert main([str(root), str(out)]) == 1
    err = capsys.readouterr().err
    assert (
        f"a3d-sunrgbd: {root / 'label' / '000003.txt'}:1: expected 'class x y w h cx cy cz hx hy hz ox oy'"
        in err
    )
    assert (
        f"a3d-sunrgbd: {root / 'image' / '000004.jpg'}: frame has no depth/000004.mat and no calib/000004.txt"
        in err
    )
    train, val = read_out(out / "train"), read_out(out / "val")
    assert list(train) == ["000001"] and list(val) == ["000002"]
    for frame, synth in ((train["000001"], frames[0]), (val["000002"], frames[1])):
        check_frame(frame, synth, "nyu19", atol=2e-5)
        np.testing.assert_allclose(frame.depth, synth.depth, atol=5e-4)  # a millimetre PNG
        np.testing.assert_allclose(frame.truth.boxes2d_visible, synth.gt.boxes2d_visible, atol=1e-6)
    check_sunrgbd_protocol_on(out / "train", train, capsys)


def check_sunrgbd_protocol_on(folder: Path, frames: dict, capsys: pytest.CaptureFixture) -> None:
    """a3d-eval --protocol sunrgbd on a folder a3d-sunrgbd wrote: its own ground truth as detections
    scores 100 on each of the 10 classes present, and the other classes are left out, counted."""
    lines = [
        FrameDetections(
            frame=name,
            R_tilt=f.R_tilt,
            class_ids=f.truth.class_ids,
            scores=np.linspace(1.0, 0.5, len(f.truth)),
            boxes2d=f.truth.boxes2d_visible,
            boxes3d=f.truth.boxes3d,
        )
        for name, f in frames.items()
    ]
    detections = folder.parent / "truth_as_detections.jsonl"
    write_detections(detections, lines)
    report = folder.parent / "eval"
    argv = [str(folder), "--detections", str(detections), "--protocol", "sunrgbd", "--out", str(report)]
    assert eval_main(argv) == 0
    assert "protocol sunrgbd" in capsys.readouterr().out
    result = json.loads((report / "eval.json").read_text())
    names = [c for f in frames.values() for c in f.truth.classes]
    ten = sorted({c for c in names if c in SUNRGBD.classes}, key=SUNRGBD.classes.index)
    assert result["protocol"]["name"] == "sunrgbd" and ten and len(ten) < len(set(names))
    assert result["present_classes"] == ten
    assert all(result["classes"][c]["ap"]["0.25"] == pytest.approx(1.0) for c in ten)
    assert result["ignored_outside_protocol"]["ground_truth"] == sum(c not in SUNRGBD.classes for c in names)


def test_without_a_split_every_frame_goes_to_all(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    frame = synth_frames((3,))[0]
    write_sun_release_frame(
        tmp_path / "NYU0001", jpeg(frame.color), np.rint(frame.depth * 1000), frame.intrinsics, None
    )
    assert main([str(tmp_path / "NYU0001"), str(tmp_path / "out"), "--depth", "filled"]) == 0
    assert "no split file found" in capsys.readouterr().out
    converted = read_out(tmp_path / "out" / "all")["NYU0001"]
    assert converted.R_tilt is None and converted.truth is None  # no extrinsics: gravity is estimated
