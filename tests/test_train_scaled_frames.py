"""The resized-frame cache of training (a3d.train.scaled_frames): the inputs it gives equal the
runtime's own on the full-size frame, flipped or not; it is written once and read after; a file
cut short is computed again."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.network.network_input import frame_network_inputs
from a3d.runtime.sources.folder import read_frame
from a3d.runtime.structures.geometry import flip_boxes_2d
from a3d.train import scaled_frames
from a3d.train.config import apply_overrides, load_config
from a3d.train.roidb import build_roidb
from a3d.train.scaled_frames import load_scaled_frame, scaled_frame_path
from tests.helpers.train_scenes import TINY, write_scenes

TRUNCATION, CONTEXT = 10.0, 1.5


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = write_scenes(tmp_path_factory.mktemp("scaled") / "frames", 3, seed=5)
    config = apply_overrides(load_config("vgg16"), TINY)
    return build_roidb(folder, config, folder.parent / "cache").records


def _full_size_inputs(record, boxes, scale, flip):
    frame = read_frame(record.ref, record.folder_intrinsics)
    color, depth = frame.color, np.load(record.filled_depth_path)
    if flip:
        color, depth = color[:, ::-1], depth[:, ::-1]
    return frame_network_inputs(color, depth, boxes, scale, TRUNCATION, CONTEXT)


@pytest.mark.parametrize("scale", [0.5, 0.4, 1.0])
@pytest.mark.parametrize("flip", [False, True])
def test_inputs_equal_the_full_size_frames(records, scale, flip):
    """Exactly at 0.5 (an integer factor of the even 48 x 64 frames) and 1.0; at 0.4 within one
    level of the uint8 colour (the resize's float rounding) and float rounding of the depth."""
    for record in records:
        boxes = record.boxes[:20].astype(np.float64)
        boxes = flip_boxes_2d(boxes, record.image_size[1]) if flip else boxes
        expect = _full_size_inputs(record, boxes, scale, flip)
        scaled = load_scaled_frame(record, scale)
        got = (scaled.flipped() if flip else scaled).network_inputs(boxes, TRUNCATION, CONTEXT)
        assert got[0].shape == expect[0].shape and got[1].shape == expect[1].shape
        if scale == 0.4:
            np.testing.assert_allclose(got[0], expect[0], atol=1.0 + 1e-4)
            np.testing.assert_allclose(got[1], expect[1], atol=1e-3)
        else:
            np.testing.assert_array_equal(got[0], expect[0])
            np.testing.assert_array_equal(got[1], expect[1])
        np.testing.assert_array_equal(got[2], expect[2])  # RoIs
        np.testing.assert_array_equal(got[3], expect[3])  # context RoIs


def test_written_once_then_read_without_the_frame(records, monkeypatch):
    record = records[0]
    path = scaled_frame_path(record, 0.5)
    path.unlink(missing_ok=True)
    first = load_scaled_frame(record, 0.5)
    assert path.is_file() and path.parent == record.filled_depth_path.parent
    assert not [p for p in path.parent.iterdir() if ".tmp-" in p.name]  # no temporaries left
    mtime = path.stat().st_mtime_ns

    def no_frame(*args, **kwargs):
        raise AssertionError("the frame was read although its resized copy is cached")

    monkeypatch.setattr(scaled_frames, "read_frame", no_frame)
    again = load_scaled_frame(record, 0.5)
    np.testing.assert_array_equal(again.color, first.color)
    np.testing.assert_array_equal(again.depth, first.depth)
    assert path.stat().st_mtime_ns == mtime
    assert again.color.dtype == np.uint8 and again.depth.dtype == np.float32


def test_a_file_cut_short_is_computed_again(records):
    record = records[1]
    good = load_scaled_frame(record, 0.5)
    path = scaled_frame_path(record, 0.5)
    path.write_bytes(path.read_bytes()[:100])
    again = load_scaled_frame(record, 0.5)
    np.testing.assert_array_equal(again.color, good.color)
    np.testing.assert_array_equal(again.depth, good.depth)
    assert path.stat().st_size > 100


def test_each_scale_has_its_own_file(records):
    record = records[2]
    assert scaled_frame_path(record, 0.5) != scaled_frame_path(record, 0.4)
    assert load_scaled_frame(record, 0.5).color.shape[:2] == (24, 32)
    assert load_scaled_frame(record, 0.4).color.shape[:2] == (19, 26)


def test_frames_whose_names_hold_dots_get_files_of_their_own(records):
    """The file is named from the whole ``NAME-KEY`` (frame names like ``scan.01`` and ``scan.02``)."""
    paths = {
        scaled_frame_path(replace(records[0], filled_depth_path=Path(f"/c/scan.0{i}-k.filled.npy")), 0.5)
        for i in (1, 2)
    }
    assert paths == {Path("/c/scan.01-k.scale0.5.npz"), Path("/c/scan.02-k.scale0.5.npz")}
