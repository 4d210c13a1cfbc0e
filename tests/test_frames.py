"""The frame folder format: exact round trips, listing, and one-line errors for each bad file."""

from __future__ import annotations

import io
import json
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.errors import InputError
from a3d.runtime.io import image_io
from a3d.runtime.sources import folder as frames
from a3d.runtime.sources import proposals_file
from a3d.runtime.sources.proposals_file import PrecomputedProposals
from a3d.runtime.structures import frame
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, rtilt_from_pitch_roll

H, W = 24, 32
K = Intrinsics(fx=500.0, fy=510.0, cx=15.5, cy=11.25)
R = rtilt_from_pitch_roll(-0.2, 0.05)


def _color(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _depth(seed: int = 0) -> np.ndarray:
    depth = np.random.default_rng(seed).uniform(0.5, 6.0, (H, W)).astype(np.float32)
    depth[:3, :5] = 0.0
    return depth


def _gt() -> GroundTruth:
    return GroundTruth.from_classes(
        ["chair", "night stand"],
        [[0.1, 0.2, 2.0, 0.6, 0.5, 0.9, 0.3], [-1.0, 0.5, 3.0, 0.5, 0.4, 0.6, -1.2]],
        [[1.5, 2.5, 10.5, 20.5], [0.0, 0.0, 5.0, 6.0]],
        [[0.5, 1.5, 12.5, 22.5], [-0.5, -0.5, 6.0, 7.0]],
        [1, 2],
    )


def _frame(folder: Path, name: str = "f", **kwargs) -> frames.FrameRef:
    frames.write_intrinsics(folder, K)
    return frames.write_frame(folder, name, _color(), _depth(), **kwargs)


def _read(ref: frames.FrameRef) -> frame.Frame:
    return frames.read_frame(ref, frames.read_folder_intrinsics(ref.color_path.parent))


def _expect(call, path: Path, *fragments: str) -> str:
    """The call raises an InputError whose single-line message starts with the path and names the problem."""
    with pytest.raises(InputError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: "), message
    for fragment in fragments:
        assert fragment in message, message
    return message


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


# ----------------------------------------------------------------------------- round trips


def test_round_trip_is_exact_with_png_depth_on_the_millimetre_grid(tmp_path: Path) -> None:
    depth_mm = np.random.default_rng(1).integers(0, 8000, (H, W)).astype(np.uint16)
    depth = depth_mm.astype(np.float32) / np.float32(1000)  # what reading a PNG gives
    instances = np.zeros((H, W), np.uint16)
    instances[2:8, 3:9] = 1
    instances[10:20, 0:6] = 2
    frames.write_intrinsics(tmp_path, K)
    ref = frames.write_frame(tmp_path, "a", _color(), depth, R_tilt=R, gt=_gt(), instances=instances)
    (listed,) = frames.list_frames(tmp_path)
    assert listed == ref
    frame = _read(listed)
    assert frame.color.dtype == np.uint8 and np.array_equal(frame.color, _color())
    assert frame.depth.dtype == np.float32 and np.array_equal(frame.depth, depth)
    assert np.array_equal(frame.R_tilt, R)  # JSON floats round-trip exactly
    assert frame.intrinsics == K and frame.warnings == ()
    gt = frames.read_ground_truth(listed)
    for field in ("class_ids", "boxes3d", "boxes2d_visible", "boxes2d_amodal", "instance_ids"):
        assert np.array_equal(getattr(gt, field), getattr(_gt(), field)), field
    assert gt.classes == ["chair", "night stand"]
    assert np.array_equal(frames.read_instances(listed), instances)
    # Writing what was read gives the same bytes: the millimetre quantisation is idempotent.
    before = ref.depth_path.read_bytes()
    frames.write_frame(tmp_path, "a", frame.color, frame.depth, R_tilt=R, gt=gt, instances=instances)
    assert ref.depth_path.read_bytes() == before


def test_png_depth_rounds_to_the_nearest_millimetre_and_npy_is_exact(tmp_path: Path) -> None:
    depth = _depth()
    png = _read(_frame(tmp_path, "p")).depth
    assert np.max(np.abs(png - depth)) <= 0.0005 + 1e-6
    assert np.array_equal(png, np.rint(depth.astype(np.float64) * 1000).astype(np.float32) / np.float32(1000))
    npy = _read(frames.write_frame(tmp_path, "n", _color(), depth, depth_format="npy")).depth
    assert np.array_equal(npy, depth)


def test_per_frame_intrinsics_override_the_folder_and_stand_in_for_it(tmp_path: Path) -> None:
    other = Intrinsics(fx=300.0, fy=301.0, cx=10.0, cy=12.0)
    ref = frames.write_frame(tmp_path, "a", _color(), _depth(), intrinsics_override=other)
    assert frames.read_folder_intrinsics(tmp_path) is None
    assert frames.read_frame(ref, None).intrinsics == other
    assert frames.read_meta(ref) == frames.FrameMeta(intrinsics=other, R_tilt=None)
    frames.write_intrinsics(tmp_path, K)
    assert _read(ref).intrinsics == other


def test_encoded_colour_bytes_are_written_unchanged(tmp_path: Path) -> None:
    jpeg = cv2.imencode(".jpg", _color(), [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    ref = frames.write_frame(tmp_path, "j", jpeg, _depth())
    assert ref.color_path.name == "j.color.jpg" and ref.color_path.read_bytes() == jpeg
    frame = frames.read_frame(ref, K)
    assert np.array_equal(frame.color, cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR))


def test_rewriting_a_frame_removes_its_stale_files(tmp_path: Path) -> None:
    _frame(tmp_path, "a", R_tilt=R, gt=_gt())
    ref = frames.write_frame(tmp_path, "a", _color(), _depth(), depth_format="npy")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["a.color.png", "a.depth.npy", "intrinsics.json"]
    assert frames.list_frames(tmp_path) == [ref]
    assert not list(tmp_path.glob(".*"))  # no temporary files left


def test_an_interrupted_rewrite_leaves_an_incomplete_frame_never_a_mixed_one(tmp_path, monkeypatch) -> None:
    _frame(tmp_path, "a")
    write = frames.atomic_write_bytes

    def disk_full_at_colour(path: Path, data: bytes) -> None:
        if ".color." in Path(path).name:
            raise OSError("disk full")
        write(path, data)

    monkeypatch.setattr(frames, "atomic_write_bytes", disk_full_at_colour)
    with pytest.raises(OSError):
        frames.write_frame(tmp_path, "a", _color(1), _depth(1))
    listing = frames.scan_folder(tmp_path)
    assert listing.frames == []
    assert [(item.path.name, item.reason) for item in listing.skipped] == [
        ("a.depth.png", "frame has no color file")
    ]


def test_all_zero_depth_is_readable_and_flagged(tmp_path: Path) -> None:
    frames.write_intrinsics(tmp_path, K)
    ref = frames.write_frame(tmp_path, "z", _color(), np.zeros((H, W), np.float32))
    frame = _read(ref)
    assert not frame.depth.any()
    assert len(frame.warnings) == 1 and "no valid pixels" in frame.warnings[0]


def test_write_frame_rejects_bad_arrays(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not fit"):
        frames.write_frame(tmp_path, "a", _color(), np.full((H, W), 70.0, np.float32))
    with pytest.raises(ValueError, match="depth is 23x32 but colour is 24x32"):
        frames.write_frame(tmp_path, "a", _color(), _depth()[1:])
    with pytest.raises(ValueError, match="needs R_tilt"):
        frames.write_frame(tmp_path, "a", _color(), _depth(), gt=_gt())
    with pytest.raises(ValueError, match="finite"):
        frames.write_frame(tmp_path, "a", _color(), np.full((H, W), np.nan, np.float32))
    assert not list(tmp_path.iterdir())  # nothing half-written


# ----------------------------------------------------------------------------- listing


def test_listing_sorts_frames_and_reports_unknown_and_incomplete_files(tmp_path: Path) -> None:
    for name in ("b", "a", "c"):
        _frame(tmp_path, name)
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "d.color.png").write_bytes((tmp_path / "a.color.png").read_bytes())  # no depth
    (tmp_path / "c.color.jpg").write_bytes(b"x")  # c now has two colour files
    (tmp_path / "sub").mkdir()
    listing = frames.scan_folder(tmp_path)
    assert [f.name for f in listing.frames] == ["a", "b"]
    reasons = {item.path.name: item.reason for item in listing.skipped}
    assert reasons["notes.txt"] == "unknown file type"
    assert "no depth" in reasons["d.color.png"]
    assert "ambiguous" in reasons["c.color.jpg"] and "ambiguous" in reasons["c.depth.png"]
    assert "folder" in reasons["sub"]
    assert [f.name for f in frames.list_frames(tmp_path)] == ["a", "b"]


def test_listing_a_missing_folder_is_an_input_error(tmp_path: Path) -> None:
    _expect(lambda: frames.list_frames(tmp_path / "nope"), tmp_path / "nope", "no such folder")


# ----------------------------------------------------------------------------- bad images


def test_truncated_png_colour(tmp_path: Path) -> None:
    ref = _frame(tmp_path)
    data = ref.color_path.read_bytes()
    ref.color_path.write_bytes(data[: len(data) - 20])  # IEND gone, last IDAT cut
    _expect(lambda: _read(ref), ref.color_path, "PNG is truncated")
    ref.color_path.write_bytes(data[:-12])  # every chunk whole, but no IEND
    _expect(lambda: _read(ref), ref.color_path, "PNG is truncated", "no IEND")


def test_truncated_jpeg_colour(tmp_path: Path) -> None:
    jpeg = cv2.imencode(".jpg", _color())[1].tobytes()
    ref = frames.write_frame(tmp_path, "j", jpeg, _depth())
    ref.color_path.write_bytes(jpeg[: len(jpeg) * 2 // 3])
    _expect(lambda: frames.read_frame(ref, K), ref.color_path, "JPEG is truncated")


def test_empty_and_unknown_and_corrupt_images(tmp_path: Path) -> None:
    ref = _frame(tmp_path)
    good = ref.color_path.read_bytes()
    ref.color_path.write_bytes(b"")
    _expect(lambda: _read(ref), ref.color_path, "empty (0 bytes)")
    ref.color_path.write_bytes(b"GIF89a....")
    _expect(lambda: _read(ref), ref.color_path, "not a PNG or JPEG")
    # Structure intact (all chunks, IEND) but the compressed data is garbage.
    idat = good.index(b"IDAT") - 4
    (length,) = struct.unpack(">I", good[idat : idat + 4])
    corrupt = good[:idat] + _png_chunk(b"IDAT", bytes(length)) + good[idat + 12 + length :]
    ref.color_path.write_bytes(corrupt)
    _expect(lambda: _read(ref), ref.color_path, "cannot decode")


def test_greyscale_and_16_bit_colour_are_rejected(tmp_path: Path) -> None:
    ref = _frame(tmp_path)
    ref.color_path.write_bytes(cv2.imencode(".png", _color()[..., 0])[1].tobytes())
    _expect(lambda: _read(ref), ref.color_path, "greyscale")
    jpeg_ref = frames.write_frame(tmp_path, "j", cv2.imencode(".jpg", _color())[1].tobytes(), _depth())
    jpeg_ref.color_path.write_bytes(cv2.imencode(".jpg", _color()[..., 0])[1].tobytes())
    _expect(lambda: _read(jpeg_ref), jpeg_ref.color_path, "greyscale")
    ref.color_path.write_bytes(cv2.imencode(".png", _color().astype(np.uint16) * 257)[1].tobytes())
    _expect(lambda: _read(ref), ref.color_path, "16-bit per channel")


def test_oversized_images_are_rejected_from_the_header_without_decoding(tmp_path, monkeypatch) -> None:
    def no_decode(*args):
        raise AssertionError("decoded an oversized image")

    monkeypatch.setattr(cv2, "imdecode", no_decode)
    ref = _frame(tmp_path)
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 2, 0, 0, 0)
    bomb = image_io._PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IEND", b"")
    ref.color_path.write_bytes(bomb)
    _expect(lambda: _read(ref), ref.color_path, "100000x100000", "above the limit")
    jpeg_path = tmp_path / "big.color.jpg"
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, 5000, 5000, 3) + b"\x01\x11\x00"
    jpeg_path.write_bytes(b"\xff\xd8" + sof + b"\xff\xd9")
    _expect(lambda: image_io.read_image_header(jpeg_path), jpeg_path, "5000x5000", "above the limit")


# ----------------------------------------------------------------------------- bad depth


def test_depth_of_another_size(tmp_path: Path) -> None:
    ref = _frame(tmp_path)
    ref.depth_path.write_bytes(cv2.imencode(".png", np.ones((H - 4, W), np.uint16) * 1000)[1].tobytes())
    _expect(lambda: _read(ref), ref.depth_path, f"depth is {H - 4}x{W} but colour is {H}x{W}")


def test_depth_png_must_be_one_channel_16_bit_millimetres(tmp_path: Path) -> None:
    ref = _frame(tmp_path)
    ref.depth_path.write_bytes(cv2.imencode(".png", np.full((H, W), 100, np.uint8))[1].tobytes())
    _expect(lambda: _read(ref), ref.depth_path, "depth PNG is 8-bit", "16-bit millimetres")
    ref.depth_path.write_bytes(cv2.imencode(".png", np.full((H, W, 3), 1000, np.uint16))[1].tobytes())
    _expect(lambda: _read(ref), ref.depth_path, "3 channels")
    ref.depth_path.write_bytes(cv2.imencode(".png", np.full((H, W), 3, np.uint16))[1].tobytes())
    _expect(lambda: _read(ref), ref.depth_path, "look like metres")


def test_npy_depth_problems(tmp_path: Path) -> None:
    frames.write_intrinsics(tmp_path, K)
    ref = frames.write_frame(tmp_path, "n", _color(), _depth(), depth_format="npy")
    cases = [
        (_depth() * 1000, "look like millimetres"),
        (np.where(_depth() > 3, np.nan, _depth()).astype(np.float32), "NaN/inf"),
        (np.full((H, W), np.inf, np.float32), "NaN/inf"),
        (-_depth(), "negative"),
        ((_depth() * 1000).astype(np.uint16), "expected float32 metres"),
        (_depth()[None], "expected (H, W)"),
    ]
    for array, fragment in cases:
        np.save(ref.depth_path, array)
        _expect(lambda: _read(ref), ref.depth_path, fragment)
    np.save(ref.depth_path, _depth())
    data = ref.depth_path.read_bytes()
    ref.depth_path.write_bytes(data[:-100])
    _expect(lambda: _read(ref), ref.depth_path, "truncated")
    ref.depth_path.write_bytes(b"not numpy at all")
    _expect(lambda: _read(ref), ref.depth_path, "not a valid .npy")


# ----------------------------------------------------------------------------- bad JSON and values


def test_missing_intrinsics(tmp_path: Path) -> None:
    ref = frames.write_frame(tmp_path, "a", _color(), _depth(), R_tilt=R)
    _expect(lambda: _read(ref), tmp_path / "intrinsics.json", "missing", "a.meta.json")


def test_malformed_json_names_the_file_line_and_column(tmp_path: Path) -> None:
    ref = _frame(tmp_path, R_tilt=R, gt=_gt())
    intrinsics = tmp_path / "intrinsics.json"
    intrinsics.write_text('{\n  "fx": 500,\n  "fy" 510\n}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), intrinsics, "malformed JSON", "line 3 column 8")
    ref.meta_path.write_text('{"R_tilt": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],}')
    _expect(lambda: frames.read_frame(ref, K), ref.meta_path, "malformed JSON", "line 1 column")
    ref.meta_path.write_text('{"R_tilt": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}')
    ref.gt_path.write_text('{"objects": [\n{"class": "chair",,}]}')
    _expect(lambda: frames.read_ground_truth(ref), ref.gt_path, "malformed JSON", "line 2 column 19")


def test_intrinsics_values_and_keys(tmp_path: Path) -> None:
    path = tmp_path / "intrinsics.json"
    path.write_text('{"fx": 500, "fy": 510, "cx": 10}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), path, "lacks cy")
    path.write_text('{"fx": -500, "fy": 510, "cx": 10, "cy": 10}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), path, "positive")
    path.write_text('{"fx": 500, "fy": NaN, "cx": 10, "cy": 10}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), path, "intrinsics.fy", "non-finite")
    path.write_text('{"fx": 500, "fy": "510", "cx": 10, "cy": 10}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), path, "intrinsics.fy must be a number")
    path.write_text('{"fx": 500, "fy": 510, "cx": 10, "cy": 10, "k1": 0.1}')
    _expect(lambda: frames.read_folder_intrinsics(tmp_path), path, "unknown key 'k1'")


def test_r_tilt_must_be_a_rotation(tmp_path: Path) -> None:
    ref = _frame(tmp_path, R_tilt=R)
    ref.meta_path.write_text(json.dumps({"R_tilt": (2 * R).tolist()}))
    _expect(lambda: _read(ref), ref.meta_path, "R_tilt", "not a proper rotation")
    ref.meta_path.write_text(json.dumps({"R_tilt": [[1, 0, 0], [0, 1, 0]]}))
    _expect(lambda: _read(ref), ref.meta_path, "R_tilt must be 3x3 numbers")
    ref.meta_path.write_text(json.dumps({"Rtilt": R.tolist()}))
    _expect(lambda: _read(ref), ref.meta_path, "unknown key 'Rtilt'")


def _objects(ref: frames.FrameRef) -> list[dict]:
    return json.loads(ref.gt_path.read_text())["objects"]


def test_ground_truth_problems(tmp_path: Path) -> None:
    ref = _frame(tmp_path, R_tilt=R, gt=_gt())
    good = _objects(ref)

    def with_object(**change) -> None:
        obj = {**good[0], **change}
        ref.gt_path.write_text(json.dumps({"objects": [good[1], obj]}))

    cases = [
        ({"class": "sofa bed"}, "objects[1].class 'sofa bed' is not one of the 19 classes"),
        ({"class": "night_stand"}, "'night_stand' is not one of"),
        ({"box3d": [0, 0, 2, 1, 1, 1]}, "objects[1].box3d must be 7 numbers"),
        ({"box3d": [0, 0, 2, 1, 1, 1, 0, 0]}, "objects[1].box3d must be 7 numbers"),
        ({"box3d": [0, 0, 2, 1, 0, 1, 0]}, "sizes l, w, h must be positive"),
        ({"box3d": [0, 0, 1e999, 1, 1, 1, 0]}, "objects[1].box3d has a non-finite value"),
        ({"box2d_visible": [1, 2, 3]}, "objects[1].box2d_visible must be 4 numbers"),
        ({"box2d_amodal": [5, 2, 3, 4]}, "x2 >= x1"),
        ({"instance": -1}, "instance must be an integer"),
        ({"colour": "red"}, "unknown key 'colour'"),
    ]
    for change, fragment in cases:
        with_object(**change)
        _expect(lambda: frames.read_ground_truth(ref), ref.gt_path, fragment)
    with_object()
    ref.meta_path.write_text("{}")
    _expect(lambda: frames.read_ground_truth(ref), ref.gt_path, "needs R_tilt")


def test_instance_map_of_another_size(tmp_path: Path) -> None:
    ref = _frame(tmp_path, instances=np.zeros((H, W), np.uint16))
    ref.instances_path.write_bytes(cv2.imencode(".png", np.zeros((H, W + 2), np.uint16))[1].tobytes())
    _expect(lambda: frames.read_instances(ref), ref.instances_path, f"is {H}x{W + 2} but colour is {H}x{W}")


# ----------------------------------------------------------------------------- precomputed proposals


def _masks() -> tuple[np.ndarray, np.ndarray]:
    masks = np.zeros((3, H, W), bool)
    masks[0, 2:6, 3:9] = True
    masks[1, :, :] = True
    masks[2, 10, 31] = True
    boxes = np.array(
        [[2.5, 1.5, 8.5, 5.5], [-0.5, -0.5, W - 0.5, H - 0.5], [30.5, 9.5, 31.5, 10.5]], np.float32
    )
    return boxes, masks


def _superpixel_proposals() -> PrecomputedProposals:
    superpixels = (np.arange(H)[:, None] // 8 * 4 + np.arange(W)[None] // 8).astype(np.int32)  # 12 cells
    return PrecomputedProposals(
        boxes=np.array([[-0.5, -0.5, 7.5, 7.5], [7.5, -0.5, 23.5, 15.5]], np.float32),
        image_size=(H, W),
        scores=np.array([0.9, 0.4], np.float32),
        superpixels=superpixels,
        indptr=np.array([0, 1, 4], np.int64),
        indices=np.array([0, 1, 2, 5], np.int32),
    )


def test_proposals_round_trip_in_both_forms(tmp_path: Path) -> None:
    boxes, masks = _masks()
    path = tmp_path / "f.proposals.npz"
    proposals_file.write_precomputed_proposals(path, PrecomputedProposals.from_masks(boxes, masks, [3, 2, 1]))
    read = proposals_file.read_precomputed_proposals(path, (H, W))
    assert len(read) == 3 and np.array_equal(read.boxes, boxes) and np.array_equal(read.scores, [3, 2, 1])
    for i in range(3):
        assert np.array_equal(read.mask(i), masks[i])
    original = _superpixel_proposals()
    proposals_file.write_precomputed_proposals(path, original)
    read = proposals_file.read_precomputed_proposals(path, (H, W))
    assert np.array_equal(read.superpixels, original.superpixels) and np.array_equal(
        read.indices, original.indices
    )
    expected = np.zeros((H, W), bool)
    expected[0:8, 8:24] = True
    expected[8:16, 8:16] = True
    assert np.array_equal(read.mask(1), expected)
    assert np.array_equal(read.mask(0), original.superpixels == 0)


def _npz(path: Path, **arrays: np.ndarray) -> Path:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())
    return path


def test_bad_proposal_files(tmp_path: Path) -> None:
    good = _superpixel_proposals()
    arrays = {k: getattr(good, k) for k in ("boxes", "scores", "superpixels", "indptr", "indices")}
    path = tmp_path / "f.proposals.npz"
    cases = [
        (
            {"superpixels": good.superpixels[:, :-1]},
            "superpixels is int32 (24, 31); expected integer (24, 32)",
        ),
        ({"indices": np.array([0, 1, 2, 12], np.int32)}, "indices must be superpixel ids in [0, 12)"),
        ({"indptr": np.array([0, 3, 2], np.int64)}, "indptr must start at 0"),
        ({"boxes": good.boxes + 10.0}, "box 1", "outside the 24x32 image"),
        ({"boxes": good.boxes[:, :3]}, "boxes is float32 (2, 3); expected float (2, 4)"),
        ({"boxes": np.full((2, 4), np.nan, np.float32)}, "non-finite"),
        ({"masks": np.zeros((2, H, 4), np.uint8)}, "either 'masks' or all of"),
        ({"extra": np.zeros(3)}, "unknown array 'extra.npy'"),
    ]
    for change, *fragments in cases:
        _npz(path, **{**arrays, **change})
        _expect(lambda: proposals_file.read_precomputed_proposals(path, (H, W)), path, *fragments)
    _npz(path, boxes=good.boxes, masks=np.zeros((2, H, 3), np.uint8))
    _expect(
        lambda: proposals_file.read_precomputed_proposals(path, (H, W)), path, "masks is uint8 (2, 24, 3)"
    )
    _npz(path, **arrays)
    path.write_bytes(path.read_bytes()[:-50])
    _expect(lambda: proposals_file.read_precomputed_proposals(path, (H, W)), path, "not a readable .npz")
