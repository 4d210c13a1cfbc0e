"""SUN RGB-D in both layouts: the conventions pinned by a hand-worked box, the readers against
a3d-synth frames written in the real formats, and a3d-run on them equal to the frame folder's."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.runtime.sources.sunrgbd import (
    ReleaseSource,
    SunOptions,
    VotenetSource,
    open_sunrgbd,
    read_point_cloud,
)
from a3d.runtime.sources.sunrgbd_conventions import (
    annotation_from_upright,
    boxes2d_from_sun,
    boxes_from_footprints,
    boxes_from_labels,
    decode_depth_png,
    depth_from_points,
    intrinsics_from_sun,
    map_class,
)
from a3d.runtime.structures.geometry import (
    Intrinsics,
    box_corners_camera,
    canonical_boxes,
    project_points,
    rtilt_from_pitch_roll,
)
from a3d.synth import SynthFrame
from tests.real_formats import (
    A,
    R_y,
    assert_same_detections,
    footprints_of,
    jpeg,
    labels_of,
    run_detections,
    sun_intrinsics,
    sun_name,
    synth_frames,
    upright_cloud,
    write_sun_release_frame,
    write_votenet_frame,
)

# The hand-worked example: a camera pitched 30 degrees down, whose SUN annotation frame is also
# turned 90 degrees about gravity: w = E c with E = R_y(90) R_x(-30).
PITCH = -math.pi / 6
R_X = rtilt_from_pitch_roll(PITCH, 0.0)
E = R_y(math.pi / 2) @ R_X
K_SUN = np.array([[500.0, 0.0, 320.5], [0.0, 500.0, 240.5], [0.0, 0.0, 1.0]])
# A box 1 m long along w's z, 1 m wide along w's x, 1 m high, centred at w = (3, 1, 0): its footprint
# points p1, p2, p3 (X, Z) and its height range (Ymin, Ymax) on w's y (down).
FOOTPRINT = [(3.5, -1.0), (3.5, 1.0), (2.5, 1.0)]
HEIGHTS = (0.5, 1.5)
# By hand: a3d's tilt frame is t = R_x c, and w = R_y(90) t, so t = R_y(90)^T w: the centre
# (3, 1, 0) is t = (0, 1, 3), w's z axis is t's -x (the 2 m edge runs along x: l = 2, w = 1,
# the orientation vector along t's z: theta = 0). In the camera frame the centre is
# R_x^T (0, 1, 3) = (0, cos30 - 3 sin30, sin30 + 3 cos30).
EXPECTED = [0.0, (math.sqrt(3) - 3) / 2, (1 + 3 * math.sqrt(3)) / 2, 2.0, 1.0, 1.0, 0.0]


def test_depth_png_values_are_shifted_millimetres_capped_at_8_m() -> None:
    # 1234 mm is stored rotated left by 3 bits: 1234 << 3 = 9872; 9000 mm (beyond 8 m) as 72000 & 0xFFFF
    # | 9000 >> 13 = 6464 | 1 = 6465.
    stored = np.array([[9872, 6465, 0]], dtype=np.uint16)
    np.testing.assert_array_equal(decode_depth_png(stored), np.array([[1.234, 8.0, 0.0]], dtype=np.float32))


def test_hand_worked_box_from_the_release_footprint_and_its_corner_pixels() -> None:
    R_tilt = rtilt_from_pitch_roll(PITCH, 0.0)
    box = boxes_from_footprints(np.array([FOOTPRINT]), np.array([HEIGHTS]), E, R_tilt)[0]
    np.testing.assert_allclose(box, EXPECTED, atol=1e-12)
    # The corners project where SUN's toolbox projects them: c = E^T w, then K (1-based pixels).
    K = intrinsics_from_sun(K_SUN)
    assert K == Intrinsics(500.0, 500.0, 319.5, 239.5)
    corners_w = np.array([(x, y, z) for x in (2.5, 3.5) for y in HEIGHTS for z in (-1.0, 1.0)])
    camera = corners_w @ E  # rows: E^T w
    toolbox = np.column_stack(
        [500 * camera[:, 0] / camera[:, 2] + 320.5, 500 * camera[:, 1] / camera[:, 2] + 240.5]
    )
    ours = project_points(box_corners_camera(box[None], R_tilt)[0], K)
    np.testing.assert_allclose(np.sort(ours, axis=0), np.sort(toolbox - 1, axis=0), atol=1e-9)
    # One by hand: w = (3.5, 1.5, 1) is t = (-1, 1.5, 3.5), camera (-1, 1.5 cos30 - 3.5 sin30,
    # 1.5 sin30 + 3.5 cos30) = (-1, -0.450962, 3.781089): pixel (500 * -1 / 3.781089 + 320.5 - 1,
    # 500 * -0.450962 / 3.781089 + 240.5 - 1).
    assert any(np.allclose(p, [187.26296, 179.86613], atol=1e-5) for p in ours)


def test_hand_worked_box_from_a_votenet_label() -> None:
    Rtilt_sun = A @ E @ A.T  # the toolbox's "matlab coordinate" tilt
    np.testing.assert_allclose(annotation_from_upright(Rtilt_sun), E, atol=1e-15)
    # The same box in the upright frame u = A w: centre (3, 0, -1); the footprint's first edge
    # (p1 -> p2, 2 m along u's y) gives hx = 1, the second (1 m along u's x) hy = 0.5; the
    # heading vector points from the centre to the first edge's midpoint, +x.
    line = "chair 11 21 40 60 3 0 -1 1 0.5 0.5 1 0".split()
    values = np.array(line[1:], dtype=np.float64)
    box = boxes_from_labels(values[4:7], values[7:10], values[10:12], Rtilt_sun, R_X)[0]
    np.testing.assert_allclose(box, EXPECTED, atol=1e-12)
    np.testing.assert_array_equal(boxes2d_from_sun(values[:4]), [[10.0, 20.0, 50.0, 80.0]])


def test_class_names_map_to_both_class_sets() -> None:
    cases = {
        "night_stand": "night stand",
        "garbage_bin": "garbage bin",
        "tv": "television",
        "chair:3": "chair",
    }
    for name, expected in cases.items():
        assert map_class(name, "nyu19") == expected
    assert map_class("night_stand", "sun10") == "night stand"
    assert map_class("garbage_bin", "sun10") is None and map_class("tv", "sun10") is None
    assert map_class("sofa_chair", "nyu19") is None and map_class("wall", "sun10") is None


def test_points_become_depth_the_nearest_winning_and_gaps_missing() -> None:
    K = Intrinsics(100.0, 100.0, 1.0, 1.0)
    Rtilt_sun = A @ R_X @ A.T
    camera = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [1.5, 0.0, 1.5], [0.0, 0.0, -1.0]])  # last: behind
    upright = camera @ A.T @ Rtilt_sun.T
    depth = depth_from_points(upright, Rtilt_sun, K, (3, 3))
    expected = np.zeros((3, 3), np.float32)
    expected[1, 1] = 2.0  # 2 m in front of 3 m on the principal point
    # (1.5, 0, 1.5) is at column 100 + 1 = 101: outside the 3-pixel image, dropped.
    np.testing.assert_allclose(depth, expected, atol=1e-12)


# ----------------------------------------------------------------------------- synth frames in SUN's formats


def a3d_folder(
    folder: Path, frames: list[SynthFrame], names: list[str], depths: list[np.ndarray], K: Intrinsics
):
    for frame, name, depth in zip(frames, names, depths, strict=True):
        write_frame(folder, name, jpeg_bytes[name], depth, R_tilt=frame.R_tilt, depth_format="npy")
    write_intrinsics(folder, K)


jpeg_bytes: dict[str, bytes] = {}


def test_release_frames_give_the_synth_frames_back(tmp_path: Path) -> None:
    frames = synth_frames()
    root = tmp_path / "SUNRGBD"
    for k, frame in enumerate(frames):
        mm = np.rint(frame.depth * 1000.0)
        folder = root / "kv1" / "NYUdata" / f"NYU{k:04d}"
        write_sun_release_frame(
            folder,
            jpeg(frame.color),
            mm,
            frame.intrinsics,
            R_y(0.4 + k) @ frame.R_tilt,
            footprints_of(frame, R_y(0.4 + k) @ frame.R_tilt),
        )
    (root / "kv1" / "NYUdata" / "notes").mkdir()  # a folder of no frame
    source = open_source(root, SourceOptions(with_truth=True))
    assert isinstance(source, ReleaseSource) and [loader.name for loader in source] == [
        "kv1__NYUdata__NYU0000",
        "kv1__NYUdata__NYU0001",
    ]
    for loader, synth in zip(source, frames, strict=True):
        frame = loader.load()
        np.testing.assert_array_equal(
            frame.depth, np.rint(synth.depth * 1000).astype(np.float32) / np.float32(1000)
        )
        np.testing.assert_allclose(frame.R_tilt, synth.R_tilt, atol=1e-12)  # the yaw about gravity is gone
        assert frame.intrinsics == sun_intrinsics(synth)
        assert frame.truth.classes == synth.gt.classes
        np.testing.assert_allclose(frame.truth.boxes3d, canonical_boxes(synth.gt.boxes3d), atol=1e-9)
        np.testing.assert_allclose(frame.truth.boxes2d_amodal, synth.gt.boxes2d_amodal, atol=1e-6)
    one = open_source(root / "kv1" / "NYUdata" / "NYU0001", SourceOptions())
    assert [loader.name for loader in one] == ["NYU0001"]


def test_run_on_release_frames_equals_run_on_the_frame_folder(tmp_path: Path, tiny_model: Path) -> None:
    frames = synth_frames()
    root, names, depths = tmp_path / "SUNRGBD" / "realsense" / "lg", [], []
    for k, frame in enumerate(frames):
        mm = np.minimum(np.rint(frame.depth * 1000.0), 8000)
        name = f"2014_10_26-{k:02d}"
        jpeg_bytes[f"realsense__lg__{name}"] = jpeg(frame.color)
        write_sun_release_frame(
            root / name, jpeg_bytes[f"realsense__lg__{name}"], mm, frame.intrinsics, R_y(-1.0) @ frame.R_tilt
        )
        names.append(f"realsense__lg__{name}")
        depths.append(mm.astype(np.float32) / np.float32(1000))
    a3d_folder(tmp_path / "frames", frames, names, depths, sun_intrinsics(frames[0]))
    expected = run_detections(tmp_path / "frames", tiny_model, tmp_path / "folder.jsonl")
    assert_same_detections(run_detections(tmp_path / "SUNRGBD", tiny_model, tmp_path / "sun.jsonl"), expected)


def votenet_tree(root: Path, frames: list[SynthFrame]) -> list[np.ndarray]:
    """The frames in VoteNet's layout (dense clouds); returns each frame's Rtilt_sun."""
    tilts = []
    for k, frame in enumerate(frames, start=1):
        Rtilt_sun = A @ (R_y(0.7) @ frame.R_tilt) @ A.T
        jpeg_bytes[f"{k:06d}"] = jpeg(frame.color)
        cloud = upright_cloud(frame.depth, frame.color, frame.intrinsics, Rtilt_sun)
        write_votenet_frame(
            root, k, jpeg_bytes[f"{k:06d}"], cloud, Rtilt_sun, frame.intrinsics, labels_of(frame, Rtilt_sun)
        )
        tilts.append(Rtilt_sun)
    return tilts


def test_votenet_frames_give_the_synth_frames_back(tmp_path: Path) -> None:
    frames = synth_frames()
    votenet_tree(tmp_path / "sunrgbd_trainval", frames)
    source = open_source(tmp_path / "sunrgbd_trainval", SourceOptions(with_truth=True))
    assert isinstance(source, VotenetSource) and [loader.name for loader in source] == ["000001", "000002"]
    for loader, synth in zip(source, frames, strict=True):
        frame = loader.load()
        np.testing.assert_array_equal(frame.depth, synth.depth)  # a dense cloud projects back exactly
        np.testing.assert_allclose(frame.R_tilt, synth.R_tilt, atol=1e-12)
        assert frame.truth.classes == synth.gt.classes
        np.testing.assert_allclose(frame.truth.boxes3d, canonical_boxes(synth.gt.boxes3d), atol=2e-5)
        np.testing.assert_allclose(frame.truth.boxes2d_visible, synth.gt.boxes2d_visible, atol=1e-6)
    sun10 = next(iter(open_sunrgbd(tmp_path / "sunrgbd_trainval", SunOptions(classes="sun10")))).load()
    assert sun10.truth.classes == [c for c in frames[0].gt.classes if map_class(sun_name(c), "sun10")]


def test_a_subsampled_cloud_gives_sparse_depth(tmp_path: Path) -> None:
    frame = synth_frames((3,))[0]
    Rtilt_sun = A @ frame.R_tilt @ A.T
    cloud = upright_cloud(frame.depth, frame.color, frame.intrinsics, Rtilt_sun)[::7]
    write_votenet_frame(tmp_path, 1, jpeg(frame.color), cloud, Rtilt_sun, frame.intrinsics, None)
    depth = next(iter(open_sunrgbd(tmp_path))).load().depth
    kept = depth > 0
    assert kept.sum() == len(cloud)
    np.testing.assert_array_equal(depth[kept], frame.depth[kept])


def test_run_on_votenet_frames_equals_run_on_the_frame_folder(tmp_path: Path, tiny_model: Path) -> None:
    frames = synth_frames()
    votenet_tree(tmp_path / "sunrgbd_trainval", frames)
    names = [f"{k:06d}" for k in (1, 2)]
    a3d_folder(tmp_path / "frames", frames, names, [f.depth for f in frames], sun_intrinsics(frames[0]))
    expected = run_detections(tmp_path / "frames", tiny_model, tmp_path / "folder.jsonl")
    got = run_detections(tmp_path / "sunrgbd_trainval", tiny_model, tmp_path / "sun.jsonl")
    assert_same_detections(got, expected)


def test_missing_scipy_is_one_line_naming_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "scipy.io", None)
    with pytest.raises(
        InputError,
        match=r"000001\.mat: reading SUN RGB-D \.mat files needs scipy: pip install 'a3d\[sunrgbd\]'",
    ):
        read_point_cloud(tmp_path / "000001.mat")


def test_bad_frames_are_one_line_each(tmp_path: Path) -> None:
    frame = synth_frames((3,))[0]
    good, bad = tmp_path / "SUNRGBD" / "a", tmp_path / "SUNRGBD" / "b"
    write_sun_release_frame(
        good, jpeg(frame.color), np.rint(frame.depth * 1000), frame.intrinsics, frame.R_tilt
    )
    write_sun_release_frame(
        bad, jpeg(frame.color), np.rint(frame.depth[:50] * 1000), frame.intrinsics, frame.R_tilt
    )
    loaders = list(open_source(tmp_path / "SUNRGBD", SourceOptions()))
    loaders[0].load()
    with pytest.raises(InputError, match=r"b\.png: depth is 50x128 but colour is 96x128 \(resize_depth=True"):
        loaders[1].load()
    resized = list(open_source(tmp_path / "SUNRGBD", SourceOptions(resize_depth=True)))[1].load()
    assert resized.depth.shape == (96, 128)


def test_depth_scale_is_refused_for_a_point_cloud_and_applies_to_release_depth(tmp_path: Path) -> None:
    frame = synth_frames((3,))[0]
    Rtilt_sun = A @ frame.R_tilt @ A.T
    cloud = upright_cloud(frame.depth, frame.color, frame.intrinsics, Rtilt_sun)
    write_votenet_frame(tmp_path / "votenet", 1, jpeg(frame.color), cloud, Rtilt_sun, frame.intrinsics, None)
    loader = next(iter(open_source(tmp_path / "votenet", SourceOptions(depth_scale=0.001))))
    with pytest.raises(InputError, match=r"000001\.mat: depth_scale: this depth is float metres"):
        loader.load()
    mm = np.rint(frame.depth * 1000)
    write_sun_release_frame(tmp_path / "NYU0001", jpeg(frame.color), mm, frame.intrinsics, frame.R_tilt)
    loaded = next(iter(open_source(tmp_path / "NYU0001", SourceOptions(depth_scale=0.0005)))).load()
    np.testing.assert_array_equal(loaded.depth, mm.astype(np.float32) / np.float32(2000))
