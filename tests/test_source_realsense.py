"""The RealSense source (a3d.runtime.sources.realsense) without a camera.

Mostly through a fake ``pyrealsense2`` at the SDK boundary (the calls a3d makes, with the SDK's
shapes: pipeline, config, align, framesets, stream profiles, the depth sensor's scale) that
serves a3d-synth frames: a3d-run's detections equal those of the same frames as a frame folder,
``--max-frames`` and Ctrl-C stop the run with whole lines and the pipeline stopped, and a missing
SDK or camera is one line. Where the real pyrealsense2 imports, the SDK also records those
frames from a software device and plays the recording back through the same source.
"""

from __future__ import annotations

import functools
import re
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import parse_line
from tests import fake_realsense
from tests.fake_realsense import DEPTH_SCALE
from tests.synth_frames import K, assert_same_detections, folder_frames, write_synth_folder

fake_sdk = functools.partial(fake_realsense.fake_sdk, intrinsics=(K.fx, K.fy, K.cx, K.cy))


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synth_folder(tmp_path_factory.mktemp("frames"))


def run(source: str, model: Path, output: Path, *flags: str) -> int:
    return run_cli.main([source, "--model", str(model), "--output", str(output), "--headless", *flags])


def test_live_frames_give_the_folders_detections(
    folder: Path, tmp_path: Path, tiny_model: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rs = fake_sdk(folder_frames(folder), serials=("111", "123"))
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    assert run(str(folder), tiny_model, tmp_path / "folder.jsonl") == 0
    # The fake camera stalls after the three frames: reported as one failed frame, exit 1.
    # A camera is live: the run takes its newest frame, so a slow first frame (the model warming
    # up) may drop one; every frame written equals the folder's frame of the same index.
    assert run("realsense:123", tiny_model, tmp_path / "camera.jsonl", "--front-end", "model") == 1
    camera = (tmp_path / "camera.jsonl").read_text().splitlines()
    folder_lines = (tmp_path / "folder.jsonl").read_text().splitlines()
    assert len(camera) >= 1  # under load the stall at the end may replace the last frame too
    for line in camera:
        index = int(parse_line(line, "camera").frame.removeprefix("realsense_"))
        (tmp_path / "one_camera.jsonl").write_text(line + "\n")
        (tmp_path / "one_folder.jsonl").write_text(folder_lines[index] + "\n")
        assert_same_detections(tmp_path / "one_camera.jsonl", tmp_path / "one_folder.jsonl", count=1)
    assert ("enable_device", "123") in rs.log and ("enable_stream", "color", "rgb8") in rs.log
    assert rs.log.count(("align",)) == 3 and rs.log[-1] == ("stop",)


def test_max_frames_stops_the_camera(
    folder: Path, tmp_path: Path, tiny_model: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rs = fake_sdk(folder_frames(folder))
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    output = tmp_path / "camera.jsonl"
    assert run("realsense", tiny_model, output, "--max-frames", "2") == 0
    names = [parse_line(line, "out").frame for line in output.read_text().splitlines()]
    assert names == ["realsense_000000", "realsense_000001"]
    # the camera is stopped; its reader may have taken one frame more meanwhile (a live source)
    assert 2 <= rs.log.count(("align",)) <= 3 and rs.log[-1] == ("stop",)


def test_a_camera_is_live_newest_frame_and_live_front_end(
    folder: Path,
    tmp_path: Path,
    tiny_model: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    rs = fake_sdk(folder_frames(folder) * 4, period=0.0)  # 12 frames at once: faster than any run
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    output = tmp_path / "camera.jsonl"
    assert run("realsense", tiny_model, output) == 1  # the stall at the end is one failed frame
    err = capsys.readouterr().err
    assert run_cli.LIVE_NOTE in err
    dropped = re.search(r"(\d+) stale frames dropped", err)
    assert dropped and int(dropped.group(1)) >= 1
    written = len(output.read_text().splitlines())
    assert written + int(dropped.group(1)) == 12  # every frame either processed or counted as dropped


def test_ctrl_c_leaves_whole_lines_and_a_stopped_camera(
    folder: Path,
    tmp_path: Path,
    tiny_model: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    rs = fake_sdk(folder_frames(folder), interrupt_at=2)
    monkeypatch.setitem(sys.modules, "pyrealsense2", rs)
    output = tmp_path / "camera.jsonl"
    assert run("realsense", tiny_model, output) == 130
    data = output.read_text()
    assert data.endswith("\n") and len(data.splitlines()) == 2
    assert rs.log[-1] == ("stop",)
    assert "interrupted after 2 frames" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("spec", "serials", "says"),
    [
        ("realsense", (), "realsense: no RealSense camera connected"),
        ("realsense:999", ("123", "456"), "realsense:999: no camera with serial 999 (connected: 123, 456)"),
    ],
)
def test_camera_absent_is_one_line_exit_2_nothing_written(
    tmp_path: Path,
    tiny_model: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
    spec: str,
    serials: tuple,
    says: str,
) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake_sdk([], serials=serials))
    output = tmp_path / "camera.jsonl"
    assert run(spec, tiny_model, output) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"a3d-run: error: {says}"]
    assert not output.exists()


def test_missing_sdk_names_the_extra(
    tmp_path: Path, tiny_model: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails as if not installed
    output = tmp_path / "camera.jsonl"
    assert run("realsense", tiny_model, output) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("a3d-run: error: realsense: the RealSense source needs pyrealsense2: ")
    assert "pip install 'a3d[realsense]'" in err[0]
    assert not output.exists()


@pytest.fixture
def real_sdk() -> types.ModuleType:
    """The installed pyrealsense2, or skip (not installed, or its libusb is missing)."""
    try:
        import pyrealsense2
    except ImportError as e:
        pytest.skip(f"pyrealsense2 does not import here ({e})")
    return pyrealsense2


def record_with_the_sdk(rs, path: Path, frames: list) -> None:
    """Record (colour BGR, depth uint16 mm) frames as the SDK records a camera: a software device
    with a depth and a colour sensor (same intrinsics, identity extrinsics) and ``rs.recorder``."""
    h, w = frames[0][1].shape
    device = rs.software_device()
    sensors = device.add_sensor("Depth"), device.add_sensor("Color")
    profiles = []
    for sensor, (kind, uid, bpp, layout) in zip(
        sensors,
        ((rs.stream.depth, 0, 2, rs.format.z16), (rs.stream.color, 1, 3, rs.format.rgb8)),
        strict=True,
    ):
        intrinsics = rs.intrinsics()
        intrinsics.width, intrinsics.height = w, h
        intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = K.fx, K.fy, K.cx, K.cy
        intrinsics.model, intrinsics.coeffs = rs.distortion.none, [0.0] * 5
        stream = rs.video_stream()
        stream.type, stream.index, stream.uid, stream.width, stream.height = kind, 0, uid, w, h
        stream.fps, stream.bpp, stream.fmt, stream.intrinsics = 30, bpp, layout, intrinsics
        profiles.append(sensor.add_video_stream(stream))
    identity = rs.extrinsics()
    identity.rotation, identity.translation = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [0.0, 0.0, 0.0]
    profiles[0].register_extrinsics_to(profiles[1], identity)
    sensors[0].add_read_only_option(rs.option.depth_units, DEPTH_SCALE)
    recorder = rs.recorder(str(path), device)
    queue = rs.frame_queue(10)
    for sensor, profile in zip(sensors, profiles, strict=True):
        sensor.open(profile)
        sensor.start(queue)
    for i, (color, depth) in enumerate(frames):
        for sensor, profile, pixels in zip(sensors, profiles, (depth, color[..., ::-1]), strict=True):
            frame = rs.software_video_frame()
            frame.pixels = np.ascontiguousarray(pixels)
            frame.bpp = pixels.itemsize * (3 if pixels.ndim == 3 else 1)
            frame.stride, frame.timestamp, frame.frame_number = frame.bpp * w, i * 1000 / 30, i
            frame.domain, frame.profile = (
                rs.timestamp_domain.hardware_clock,
                profile.as_video_stream_profile(),
            )
            sensor.on_video_frame(frame)
        time.sleep(1 / 30)  # recorded at the camera's rate: the SDK's playback replays arrival times
    for sensor in sensors:
        sensor.stop()
        sensor.close()
    del recorder  # the recording is written when the recorder goes


PLAYS = 5


def test_the_sdk_plays_its_own_recording_through_the_source(
    real_sdk: types.ModuleType, folder: Path, tmp_path: Path, tiny_model: Path
) -> None:
    rs = real_sdk
    frames = folder_frames(folder)
    recording = tmp_path / "recording.db3"  # pyrealsense2 >= 2.56 records ROS 2 (.db3); older: .bag
    record_with_the_sdk(rs, recording, frames)
    from a3d.runtime.sources.realsense import RealSenseSource
    from a3d.runtime.sources.registry import SourceOptions

    # pyrealsense2 2.59's playback of so short a recording sometimes delivers no frameset at all
    # (about 1 play in 4 here, whatever the real-time and pause settings): the source reports that
    # as a failed frame, and the test plays the recording up to PLAYS times.
    for _ in range(PLAYS):
        source = RealSenseSource(f"realsense:{recording}", SourceOptions())
        assert source.depth_scale == pytest.approx(DEPTH_SCALE)
        assert source.intrinsics.fx == pytest.approx(K.fx, rel=1e-6)
        loaders = list(source)
        if len(loaders) >= 2:  # the SDK's syncer may drop the first frameset
            break
        with pytest.raises(InputError, match="the SDK's playback delivered no frames"):
            loaders[0].load()
    got = [loader.load() for loader in loaders]
    assert len(got) >= 2
    for frame in got:
        i = next(i for i, (color, _) in enumerate(frames) if np.array_equal(frame.color, color))
        depth = frames[i][1].astype(np.float32) / 1000
        both = (frame.depth > 0) & (depth > 0)
        assert both.sum() >= 0.95 * (depth > 0).sum()  # rs.align keeps (nearly) every pixel here
        assert np.mean(frame.depth[both] == depth[both]) >= 0.99
    output = tmp_path / "recording.jsonl"
    for _ in range(PLAYS):
        code = run(f"realsense:{recording}", tiny_model, output)
        if code == 0:  # exit 1: the playback delivered no frames
            break
    assert code == 0
    assert 1 <= len(output.read_text().splitlines()) <= len(frames)  # the syncer's drop varies by run


def test_the_sdk_reads_the_layout_of_the_sdk_bags_the_bag_tests_write(
    real_sdk: types.ModuleType, folder: Path, tmp_path: Path
) -> None:
    """The RealSense-layout bag of tests/test_source_bag.py played by the SDK itself: the SDK
    finds both streams with the intrinsics, and the depth-to-colour extrinsics, that a3d's bag
    reader takes from it (the SDK is the authority on what its ``tf/0`` topics mean)."""
    pytest.importorskip("rosbags")
    import cv2

    from a3d.runtime.sources.registry import SourceOptions, open_source
    from a3d.synth.depth_camera import offset_depth_camera
    from tests.bag_files import write_sdk_bag

    rs = real_sdk
    calibration, depth_size = offset_depth_camera(folder_frames(folder)[0][1].shape)
    frames = [(color, np.full(depth_size, 2000, np.uint16)) for color, _ in folder_frames(folder)]
    path = tmp_path / "sdk.bag"
    turn = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    write_sdk_bag(path, frames, K, calibration, reference_to_color=(turn, np.array([0.01, 0.0, 0.0])))
    plan = open_source(path, SourceOptions()).plan

    config = rs.config()
    config.enable_device_from_file(str(path), False)
    pipeline = rs.pipeline()
    profile = pipeline.start(config)
    try:
        depth = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        color = profile.get_stream(rs.stream.color).as_video_stream_profile()
        extrinsics = depth.get_extrinsics_to(color)
        R = np.array(extrinsics.rotation).reshape(3, 3).T  # the SDK's rotation is column-major
        np.testing.assert_allclose(R, plan.calibration.R, atol=1e-6)
        np.testing.assert_allclose(extrinsics.translation, plan.calibration.t, atol=1e-6)
        for sdk, ours in (
            (depth.get_intrinsics(), plan.calibration.depth_intrinsics),
            (color.get_intrinsics(), K),
        ):
            assert (sdk.fx, sdk.fy, sdk.ppx, sdk.ppy) == pytest.approx(
                (ours.fx, ours.fy, ours.cx, ours.cy), rel=1e-6
            )
    finally:
        pipeline.stop()
