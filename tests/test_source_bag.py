"""Bags as a frame source (a3d.runtime.sources.bag): ROS 1 and ROS 2 bags and a RealSense SDK
recording written with rosbags from a3d-synth frames give the frames, and a3d-run the detections,
of the same frames as an a3d frame folder; and every way a bag can be unusable is one line."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")

from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.sources.bag import BagSource
from a3d.runtime.sources.folder import FolderSource, write_frame, write_intrinsics
from a3d.runtime.sources.registry import SourceOptions, open_source
from a3d.synth.depth_camera import offset_depth_camera, render_depth_from
from a3d.synth.scene import generate_frame
from tests.bag_files import (
    ALIGNED,
    COLOR,
    COLOR_INFO,
    RAW_DEPTH,
    RAW_DEPTH_INFO,
    _Bag,
    write_driver_bag,
    write_sdk_bag,
)
from tests.synth_frames import (
    CONFIG,
    SEEDS,
    SIZE,
    K,
    assert_same_detections,
    folder_frames,
    write_synth_folder,
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synth_folder(tmp_path_factory.mktemp("frames"))


def frames_of(source) -> list:
    return [loader.load() for loader in source]


@pytest.mark.parametrize("ros2", [False, True], ids=["ros1", "ros2"])
@pytest.mark.parametrize("depth_32f", [False, True], ids=["16UC1", "32FC1"])
def test_driver_bag_frames_equal_the_folders(
    folder: Path, tmp_path: Path, ros2: bool, depth_32f: bool
) -> None:
    path = tmp_path / ("bag" if ros2 else "frames.bag")
    write_driver_bag(path, folder_frames(folder), K, ros2=ros2, depth_32f=depth_32f)
    source = open_source(path, SourceOptions())
    assert isinstance(source, BagSource) and source.incomplete == []
    assert (source.plan.color_topic, source.plan.depth_topic) == (COLOR, ALIGNED)
    assert source.plan.calibration is None  # aligned_depth_to_color: registered already
    got, want = frames_of(source), frames_of(FolderSource(folder))
    assert len(got) == len(want) == 3
    for a, b in zip(got, want, strict=True):
        assert a.intrinsics == b.intrinsics and a.R_tilt is None
        assert np.array_equal(a.color, b.color)
        np.testing.assert_allclose(a.depth, b.depth, rtol=0, atol=1e-6 if depth_32f else 0)
    assert [f.timestamp for f in got] == pytest.approx([1_700_000_000.0 + i / 30 for i in range(3)], abs=1e-6)


def run(source: Path, model: Path, output: Path, *flags: str) -> int:
    return run_cli.main([str(source), "--model", str(model), "--output", str(output), "--headless", *flags])


@pytest.mark.parametrize("ros2", [False, True], ids=["ros1", "ros2"])
def test_a3d_run_on_a_bag_detects_what_it_detects_on_the_folder(
    folder: Path, tmp_path: Path, tiny_model: Path, ros2: bool
) -> None:
    path = tmp_path / ("bag" if ros2 else "frames.bag")
    write_driver_bag(path, folder_frames(folder), K, ros2=ros2)
    assert run(folder, tiny_model, tmp_path / "folder.jsonl") == 0
    assert run(path, tiny_model, tmp_path / "bag.jsonl") == 0
    assert_same_detections(tmp_path / "bag.jsonl", tmp_path / "folder.jsonl")


def sdk_frames(folder: Path, units: float = 0.0001) -> tuple[list, object, list[np.ndarray]]:
    """Colour from the folder and depth as an offset depth camera sees it, in ``units``; the
    calibration, and each frame's depth rendered in the colour camera (for comparison)."""
    calibration, depth_size = offset_depth_camera(SIZE)
    exact = replace(CONFIG, noise=False)
    frames, truth = [], []
    for (color, _), seed in zip(folder_frames(folder), SEEDS, strict=True):
        seen = render_depth_from(seed, exact, calibration, depth_size)
        frames.append((color, np.round(seen / units).astype(np.uint16)))
        truth.append(generate_frame(seed, exact).depth_exact)
    return frames, calibration, truth


def test_realsense_sdk_bag_depth_is_registered_to_colour(folder: Path, tmp_path: Path) -> None:
    frames, calibration, truth = sdk_frames(folder)
    path = tmp_path / "sdk.bag"
    turn = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    write_sdk_bag(
        path, frames, K, calibration, depth_units=0.0001, reference_to_color=(turn, np.array([0.01, 0, 0]))
    )
    source = open_source(path, SourceOptions())
    got = source.plan.calibration
    assert got is not None and got.depth_intrinsics == calibration.depth_intrinsics
    np.testing.assert_allclose(got.R, calibration.R, atol=1e-6)
    np.testing.assert_allclose(got.t, calibration.t, atol=1e-6)
    assert source.plan.depth_scale == pytest.approx(0.0001)
    within = both = 0
    for frame, depth in zip(frames_of(source), truth, strict=True):
        assert frame.depth.shape == SIZE and frame.intrinsics == K
        have = (frame.depth > 0) & (depth > 0)
        within += np.count_nonzero(np.abs(frame.depth - depth)[have] <= 0.001)
        both += np.count_nonzero(have)
    assert both > 0.7 * 3 * SIZE[0] * SIZE[1] and within / both >= 0.95


def test_a3d_run_on_an_sdk_bag_equals_the_folder_of_its_registered_frames(
    folder: Path, tmp_path: Path, tiny_model: Path
) -> None:
    frames, calibration, _ = sdk_frames(folder)
    path = tmp_path / "sdk.bag"
    write_sdk_bag(path, frames, K, calibration, depth_units=0.0001)
    registered = tmp_path / "registered"
    registered.mkdir()
    write_intrinsics(registered, K)
    for i, frame in enumerate(frames_of(open_source(path, SourceOptions()))):
        write_frame(registered, f"r{i}", frame.color, frame.depth, depth_format="npy")
    assert run(registered, tiny_model, tmp_path / "folder.jsonl") == 0
    assert run(path, tiny_model, tmp_path / "bag.jsonl") == 0
    assert_same_detections(tmp_path / "bag.jsonl", tmp_path / "folder.jsonl")


def test_unpaired_colour_images_are_counted_once(folder: Path, tmp_path: Path) -> None:
    path = tmp_path / "late.bag"
    write_driver_bag(path, folder_frames(folder), K, lag=1.0)  # beyond the 0.02 s tolerance
    source = open_source(path, SourceOptions())
    assert len(source) == 0
    assert source.incomplete == [f"{path}: 3 of 3 colour images have no depth image within 0.02 s (skipped)"]


def test_an_ambiguous_topic_is_named_and_can_be_chosen(folder: Path, tmp_path: Path) -> None:
    path = tmp_path / "two.bag"
    with _Bag(path, ros2=False) as bag:
        m = bag.m
        for i, (color, depth) in enumerate(folder_frames(folder)):
            stamp = 100.0 + i
            for topic in (COLOR, "/camera2/color/image_raw"):
                bag.add(topic, m.image(stamp, "cam", color[..., ::-1], "bgr8"), stamp)
            bag.add(COLOR_INFO, m.camera_info(stamp, "cam", K, SIZE), stamp)
            bag.add(ALIGNED, m.image(stamp, "cam", depth, "16UC1"), stamp)
    with pytest.raises(InputError) as error:
        open_source(path, SourceOptions())
    assert str(error.value) == (
        f"{path}: several colour (rgb8/bgr8/rgba8/bgra8 or compressed) image topics "
        "(/camera/color/image_raw, /camera2/color/image_raw); choose one with --color-topic"
    )
    source = open_source(path, SourceOptions(extra={"color_topic": COLOR}))
    frame = frames_of(source)[0]
    assert source.plan.color_topic == COLOR
    assert np.array_equal(frame.color, folder_frames(folder)[0][0][..., ::-1])  # bgr8 read as BGR
    with pytest.raises(InputError, match="--color-topic: /nope is not a topic"):
        open_source(path, SourceOptions(extra={"color_topic": "/nope"}))


def test_depth_that_may_be_unregistered_is_refused_in_one_line(folder: Path, tmp_path: Path) -> None:
    path = tmp_path / "raw.bag"
    write_driver_bag(path, folder_frames(folder), K, with_aligned=False)
    with pytest.raises(InputError) as error:
        open_source(path, SourceOptions())
    assert str(error.value) == (
        f"{path}: cannot tell whether /camera/depth/image_rect_raw is registered to colour (no camera_info "
        "for it); record aligned_depth_to_color or pick a registered depth topic with depth_topic=TOPIC"
    )


@pytest.mark.parametrize(
    ("case", "says"),
    [
        (
            "no_depth",
            ": no depth (16UC1/32FC1) image topic "
            "(topics: /camera/color/camera_info, /camera/color/image_raw)",
        ),
        ("sdk_no_extrinsics", ": registration not possible: the recording has no Depth_0 extrinsics (tf/0)"),
        ("sdk_no_colour", ": RealSense recording without a colour stream (no .../Color_0/image/data)"),
        ("missing_extra", ": reading bags needs rosbags: pip install 'a3d[bag]'"),
    ],
)
def test_an_unusable_bag_is_one_line_exit_2_and_nothing_written(
    folder: Path,
    tmp_path: Path,
    tiny_model: Path,
    capsys: pytest.CaptureFixture,
    monkeypatch: pytest.MonkeyPatch,
    case: str,
    says: str,
) -> None:
    path = tmp_path / "bad.bag"
    if case == "no_depth" or case == "missing_extra":
        write_driver_bag(
            path, folder_frames(folder), K, with_aligned=False, with_raw_depth=case != "no_depth"
        )
    else:
        frames, calibration, _ = sdk_frames(folder)
        write_sdk_bag(
            path,
            frames,
            K,
            calibration,
            with_extrinsics=case != "sdk_no_extrinsics",
            with_color=case != "sdk_no_colour",
        )
    if case == "missing_extra":
        monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)  # import fails as if not installed
    output = tmp_path / "out.jsonl"
    assert run(path, tiny_model, output) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"a3d-run: error: {path}{says}"]
    assert not output.exists()


@pytest.mark.parametrize("frame_id", ["cam", "depth_cam"])
@pytest.mark.parametrize("tf", [False, True], ids=["no_tf", "tf_static"])
def test_unaligned_depth_topic_registration_is_told_by_frame_id_and_tf_static(
    folder: Path, tmp_path: Path, frame_id: str, tf: bool
) -> None:
    """A depth topic without 'aligned' in its name is registered already when its camera_info has
    the colour camera's frame_id; else it is registered with the transform the /tf_static tree
    gives (link -> cam, link -> depth_cam), and refused in one line without one."""
    path = tmp_path / "frames"  # ROS 2: rosbags' ROS 1 Noetic store has no tf2_msgs
    to_cam = (cv2.Rodrigues(np.array([0.0, 0.03, 0.0]))[0], np.array([0.0, 0.0, 0.01]))
    to_depth = (np.eye(3), np.array([0.05, 0.0, 0.0]))
    with _Bag(path, ros2=True) as bag:
        m, t = bag.m, bag.m.t
        if tf:
            stamped = [
                t["geometry_msgs/msg/TransformStamped"](
                    header=m.header(100.0, "link"), child_frame_id=child, transform=m.transform(*pose)
                )
                for child, pose in (("cam", to_cam), ("depth_cam", to_depth))
            ]
            bag.add("/tf_static", t["tf2_msgs/msg/TFMessage"](transforms=stamped), 100.0)
        for i, (color, depth) in enumerate(folder_frames(folder)):
            stamp = 100.0 + i
            bag.add(COLOR, m.image(stamp, "cam", color[..., ::-1], "rgb8"), stamp)
            bag.add(COLOR_INFO, m.camera_info(stamp, "cam", K, SIZE), stamp)
            bag.add(RAW_DEPTH, m.image(stamp, frame_id, depth, "16UC1"), stamp)
            bag.add(RAW_DEPTH_INFO, m.camera_info(stamp, frame_id, K, SIZE), stamp)
    if frame_id == "cam":
        assert open_source(path, SourceOptions()).plan.calibration is None
    elif not tf:
        with pytest.raises(InputError) as error:
            open_source(path, SourceOptions())
        assert str(error.value) == (
            f"{path}: registration not possible: {RAW_DEPTH} is in frame 'depth_cam', colour in 'cam', "
            "and /tf_static does not connect them; record aligned_depth_to_color"
        )
    else:
        calibration = open_source(path, SourceOptions()).plan.calibration
        # p_link = Rc p_cam + tc = p_depth + td  =>  p_cam = Rc^T (p_depth + td - tc)
        np.testing.assert_allclose(calibration.R, to_cam[0].T, atol=1e-9)
        np.testing.assert_allclose(calibration.t, to_cam[0].T @ (to_depth[1] - to_cam[1]), atol=1e-9)
