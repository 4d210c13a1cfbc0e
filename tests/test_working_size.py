"""Frames larger than the working size: brought down to it with their camera before the pipeline
runs, their detections' 2D boxes back in their own pixels, the same objects as the frame at the
working size itself; frames no larger, or with proposals cut for their size, as they come."""

from __future__ import annotations

import logging
from dataclasses import replace

import cv2
import numpy as np
import pytest

from a3d.runtime.detector import Detector
from a3d.runtime.frontend.working_size import WORKING_SIDE, working_frame
from a3d.runtime.pipeline import PipelineConfig, finish, infer, prepare
from a3d.runtime.sources.proposals_file import PrecomputedProposals
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from a3d.train import loop
from a3d.train.cli import main as train_main
from tests.helpers.runtime_frames import FakeModel, H, K, W, scene
from tests.helpers.train_scenes import tiny_train_args, write_scenes


def frame_at(factor: int, seed: int = 0) -> Frame:
    """The test scene, each pixel repeated ``factor`` x ``factor`` times, with its camera."""
    color, depth = scene(seed)
    size = (W * factor, H * factor)
    color = cv2.resize(color, size, interpolation=cv2.INTER_NEAREST)
    depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    R = rtilt_from_pitch_roll(np.radians(-8.0), np.radians(1.5))
    return Frame(name="f", color=color, depth=depth, intrinsics=K.resized(factor, factor), R_tilt=R)


def test_a_frame_over_the_working_side_comes_down_to_it_with_its_camera() -> None:
    small, big = frame_at(1), frame_at(2)
    working = working_frame(big, W)
    assert working.frame.image_size == (H, W) and (working.sx, working.sy) == (0.5, 0.5)
    np.testing.assert_array_equal(working.frame.color, small.color)  # the area of 2 x 2 equal pixels
    np.testing.assert_array_equal(working.frame.depth, small.depth)  # nearest: no depth invented
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(working.frame.intrinsics, name) == pytest.approx(getattr(K, name), abs=1e-12)
    upright = replace(big, color=np.ascontiguousarray(big.color.transpose(1, 0, 2)), depth=big.depth.T.copy())
    assert working_frame(upright, W).frame.image_size == (W, H)  # the longer side, standing or lying
    for kept in (working_frame(small, W), *(working_frame(big, side) for side in (None, 0, 2 * W))):
        assert kept.frame is small or kept.frame is big
        box = np.array([[1.0, 2.0, 3.0, 4.0]])
        np.testing.assert_array_equal(kept.to_native(box), box)


def test_boxes_go_back_to_the_frames_own_pixels_inside_its_image() -> None:
    working = working_frame(frame_at(2), W)
    extent = np.array([[-0.5, -0.5, W - 0.5, H - 0.5]])
    np.testing.assert_allclose(working.to_native(extent), [[-0.5, -0.5, 2 * W - 0.5, 2 * H - 0.5]])
    np.testing.assert_allclose(working.to_native(np.array([[10.0, 5.0, W + 3.0, 20.0]])),
                               [[20.5, 10.5, 2 * W - 0.5, 40.5]])  # fmt: skip


def test_a_frame_twice_the_working_side_gives_the_detections_of_the_frame_at_it() -> None:
    model = FakeModel()
    config = replace(PipelineConfig.from_metadata(model.metadata), working_side=W)
    small, big = frame_at(1, seed=2), frame_at(2, seed=2)
    expected = finish(prepared := prepare(small, config), infer(model, prepared), config)
    prepared_big = prepare(big, config)
    got = finish(prepared_big, infer(model, prepared_big), config)
    assert len(expected) > 5
    assert prepared_big.frame is big and prepared_big.work.image_size == (H, W)
    np.testing.assert_array_equal(got.class_ids, expected.class_ids)
    np.testing.assert_allclose(got.scores, expected.scores, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.boxes3d, expected.boxes3d, rtol=0, atol=1e-9)  # metric: unchanged
    for native, working in ((got.boxes2d, expected.boxes2d), (got.boxes2d_amodal, expected.boxes2d_amodal),
                            (prepared_big.native_boxes, prepared.boxes)):  # fmt: skip
        np.testing.assert_allclose(native, (working + 0.5) * 2 - 0.5, rtol=0, atol=1e-9)
    assert got.intrinsics == big.intrinsics  # what draws the line on the frame as it came
    as_it_comes = prepare(big, replace(config, working_side=None))
    assert as_it_comes.work is big and as_it_comes.rois.max() > prepared_big.rois.max()


def test_a_frame_with_proposals_cut_for_its_size_keeps_it_unless_they_are_computed_anyway() -> None:
    model = FakeModel()
    config = replace(PipelineConfig.from_metadata(model.metadata), working_side=W)
    big = frame_at(2)
    masks = np.zeros((1, 2 * H, 2 * W), bool)
    masks[0, 10:60, 20:90] = True
    own = replace(big, proposals=PrecomputedProposals.from_masks([[19.5, 9.5, 89.5, 59.5]], masks))
    kept = prepare(own, config)
    assert kept.work is own and kept.notes == [
        f"{2 * W} x {2 * H} kept for its precomputed proposals: the network works best at {W} across "
        "(--proposals compute brings it there)"]  # fmt: skip
    computed = prepare(own, replace(config, proposal_source="compute"))
    assert computed.work.image_size == (H, W) and computed.work.proposals is None and not computed.notes



def test_the_python_api_brings_frames_to_the_working_side_unless_told_not_to() -> None:
    assert Detector.load("live", threads=1).config.working_side == WORKING_SIDE
    assert Detector.load("live", threads=1, working_side=None).config.working_side is None
    big = frame_at(2)
    as_it_comes = Detector.load("live", threads=1, working_side=0)  # as a3d-run's --working-side 0
    assert prepare(big, as_it_comes.config).work is big


def test_training_on_frames_larger_than_the_working_size_says_so(
    tmp_path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    frames = write_scenes(tmp_path / "frames", 2, seed=3)
    for side, said in ((WORKING_SIDE, False), (40, True)):  # the scenes' frames are 48 x 64
        monkeypatch.setattr(loop, "WORKING_SIDE", side)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger=loop.__name__):
            args = tiny_train_args(frames, tmp_path / f"run{side}", tmp_path / "cache")
            assert train_main([*args, "--iters", "1"]) == 0
        assert ("2 of the 2 training frames are larger than 40 pixels across" in caplog.text) == said
