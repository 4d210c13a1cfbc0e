"""Property-based tests (hypothesis): the readers of untrusted files on random and mutated bytes.

Each reader is fed random byte strings, valid files with random byte edits (flips, cuts,
insertions, deletions) and, for JSON, valid documents with a random part replaced by any JSON
value (huge integers, NaN, deep nesting included). It must either return data that holds its
documented invariants (finite values, matching sizes, a proper rotation) or raise a ValueError
(InputError is one) whose message is one line naming the file. Anything else (a crash, another
exception type, a message without the file, NaN passed on silently) fails.
"""

from __future__ import annotations

import functools
import io
import json
import struct
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from a3d.runtime.errors import InputError
from a3d.runtime.io import image_io
from a3d.runtime.io.detections_io import FrameDetections, format_line, parse_line
from a3d.runtime.sources.folder import FrameRef, read_frame, read_ground_truth, write_frame
from a3d.runtime.sources.proposals_file import (
    PrecomputedProposals,
    read_precomputed_proposals,
    write_precomputed_proposals,
)
from a3d.runtime.structures.classes import NUM_CLASSES
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, is_rotation, rtilt_from_pitch_roll

SETTINGS = settings(
    max_examples=120,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
H, W = 12, 16
K = Intrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5)
R_TILT = rtilt_from_pitch_roll(np.radians(-10.0), np.radians(2.0))
RNG = np.random.default_rng(3)
COLOR = RNG.integers(0, 255, (H, W, 3), dtype=np.uint8)
DEPTH = np.where(RNG.random((H, W)) < 0.1, 0.0, RNG.uniform(0.5, 5.0, (H, W))).astype(np.float32)
GT = GroundTruth.from_classes(
    ["chair", "table"],
    [[0.1, 0.2, 2.0, 0.6, 0.5, 0.9, 0.3], [-0.4, 0.3, 3.0, 1.2, 0.8, 0.7, -1.0]],
    [[1.0, 2.0, 6.0, 9.0], [7.0, 1.0, 15.0, 8.0]],
    [[0.5, 1.5, 6.5, 10.0], [6.0, 0.5, 15.5, 9.0]],
    [1, 2],
)


def _png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def _valid_files(folder: Path) -> dict[str, bytes]:
    """The bytes of one valid frame's files, as a3d writes them, plus a JPEG colour and .npy depth."""
    write_frame(folder, "v", COLOR, DEPTH, R_tilt=R_TILT, intrinsics_override=K, gt=GT)
    files = {p.name.removeprefix("v."): p.read_bytes() for p in folder.glob("v.*")}
    files["color.jpg"] = cv2.imencode(".jpg", COLOR)[1].tobytes()
    files["depth.npy"] = _npy(DEPTH)
    return files


def _proposal_files(folder: Path) -> list[bytes]:
    """Valid proposals archives, one per segment form (packed masks; superpixels + CSR)."""
    masks = RNG.random((3, H, W)) < 0.3
    boxes = np.array([[0.5, 0.5, 9.5, 8.5], [2.0, 1.0, 15.0, 11.0], [-0.5, -0.5, 4.0, 3.0]])
    sp = PrecomputedProposals(
        boxes=boxes.astype(np.float32),
        image_size=(H, W),
        scores=np.array([0.9, 0.5, 0.1], np.float32),
        superpixels=RNG.integers(0, 6, (H, W)).astype(np.int32),
        indptr=np.array([0, 2, 3, 6]),
        indices=np.array([0, 1, 2, 3, 4, 5], np.int32),
    )
    out = []
    for i, proposals in enumerate((PrecomputedProposals.from_masks(boxes, masks), sp)):
        path = folder / f"p{i}.proposals.npz"
        write_precomputed_proposals(path, proposals)
        out.append(path.read_bytes())
    return out


def _detections_line() -> str:
    boxes3d = np.array([[0.1, 0.2, 2.0, 0.6, 0.5, 0.9, 0.3], [-0.4, 0.3, 3.0, 1.2, 0.8, 0.7, -1.0]])
    return format_line(
        FrameDetections(
            frame="v",
            R_tilt=R_TILT,
            class_ids=np.array([3, NUM_CLASSES - 1]),
            scores=np.array([0.9, 0.25]),
            boxes2d=np.array([[1.0, 2.0, 6.0, 9.0], [7.0, 1.0, 15.0, 8.0]]),
            boxes3d=boxes3d,
            color="v.color.png",
            depth="v.depth.png",
            timing={"total": 0.5},
            boxes2d_amodal=np.array([[0.5, 1.5, 6.5, 10.0], [6.0, 0.5, 15.5, 9.0]]),
        )
    )


@functools.cache
def _valid() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as folder:
        return {
            **_valid_files(Path(folder)),
            "proposals": _proposal_files(Path(folder)),
            "line": _detections_line(),
        }


@pytest.fixture
def valid() -> dict[str, Any]:
    """The valid files' bytes (with a short repr: hypothesis prints the arguments of a failing example)."""
    return _Valid(_valid())


class _Valid(dict):
    def __repr__(self) -> str:
        return "<valid files>"


# ----------------------------------------------------------------------------- strategies


@st.composite
def mutated(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` with 1-4 random edits: byte flips, a cut, an insertion or a deletion."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "flip", "cut", "insert", "delete"]))
        at = draw(st.integers(0, max(len(out) - 1, 0)))
        if kind == "flip" and out:
            out[at] ^= draw(st.integers(1, 255))
        elif kind == "cut":
            del out[at:]
        elif kind == "insert":
            out[at:at] = draw(st.binary(min_size=1, max_size=16))
        else:
            del out[at : at + draw(st.integers(1, 64))]
    return bytes(out)


def files(*sources: bytes) -> st.SearchStrategy[bytes]:
    """Random bytes (sometimes starting with a real signature), or one of ``sources`` mutated."""
    signature = st.sampled_from([b"", image_io._PNG_SIGNATURE, b"\xff\xd8", b"\x93NUMPY", b"PK\x03\x04"])
    noise = st.builds(lambda head, tail: head + tail, signature, st.binary(max_size=300))
    return st.one_of(noise, *(mutated(s) for s in sources))


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(10**308, 10**330)  # beyond float64: int too large to convert to float
    | st.floats()  # NaN and +-inf are written as NaN / Infinity, which json.loads accepts
    | st.text(max_size=8),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=12,
)


@st.composite
def edited_json(draw: st.DrawFn, document: Any) -> str:
    """``document`` with one random part (a value, or the whole) replaced by any JSON value."""
    replacement = draw(json_values)

    def edit(value: Any) -> Any:
        if not isinstance(value, (dict, list)) or not value or draw(st.integers(0, 3)) == 0:
            return replacement
        if isinstance(value, dict):
            key = draw(st.sampled_from(sorted(value)))
            if draw(st.integers(0, 5)) == 0:  # a new, unknown key
                return {**value, draw(st.text(max_size=6)): replacement}
            return {**value, key: edit(value[key])}
        i = draw(st.integers(0, len(value) - 1))
        return [*value[:i], edit(value[i]), *value[i + 1 :]]

    return json.dumps(edit(document), allow_nan=True)


def json_files(source: bytes) -> st.SearchStrategy[bytes]:
    document = json.loads(source)
    edits = edited_json(document).map(str.encode)
    return st.one_of(files(source), edits)


DEEP_JSON = b"[" * 100_000  # json.loads: RecursionError, unless the reader catches it
HUGE_INTEGER = b"1" * 5000  # json.loads: ValueError above 4300 digits, without the file's name


# ----------------------------------------------------------------------------- checks


def outcome(read: Callable[[], Any], *paths: Path | str) -> Any:
    """``read()``'s result, or None if it raised a ValueError (InputError is one) whose message is
    one line starting with one of ``paths`` ("PATH: problem"); any other exception propagates and
    fails the test."""
    try:
        return read()
    except ValueError as error:
        message = str(error)
        assert "\n" not in message, message
        named = any(message.startswith(f"{path}:") for path in paths)
        assert named, (
            f"{type(error).__name__} does not start with one of {[str(p) for p in paths]}: {message}"
        )
        return None


def _frame_folder(folder: Path, valid: dict[str, Any], **replaced: bytes) -> FrameRef:
    """Frame "f" in ``folder`` from the valid files, with ``replaced`` ({"color_png": bytes, ...})."""
    for old in folder.glob("f.*"):
        old.unlink()
    parts = {
        "color.png": valid["color.png"],
        "depth.png": valid["depth.png"],
        "meta.json": valid["meta.json"],
    }
    for key, data in replaced.items():
        suffix = key.replace("_", ".")
        role = suffix.split(".")[0]
        parts = {k: v for k, v in parts.items() if not k.startswith(role)} | {suffix: data}
    for suffix, data in parts.items():
        (folder / f"f.{suffix}").write_bytes(data)
    color, depth, meta = (next(s for s in parts if s.startswith(role)) for role in ("color", "depth", "meta"))
    return FrameRef("f", folder / f"f.{color}", folder / f"f.{depth}", meta_path=folder / f"f.{meta}")


def _check_frame(ref: FrameRef) -> None:
    files = (ref.color_path, ref.depth_path, ref.meta_path, ref.color_path.parent / "intrinsics.json")
    frame = outcome(lambda: read_frame(ref, None), *files)
    if frame is None:
        return
    assert frame.color.dtype == np.uint8 and frame.color.ndim == 3 and frame.color.shape[2] == 3
    assert frame.color.shape[:2] == frame.depth.shape == frame.image_size
    assert frame.depth.dtype == np.float32 and np.isfinite(frame.depth).all() and (frame.depth >= 0).all()
    K = frame.intrinsics
    assert np.isfinite([K.fx, K.fy, K.cx, K.cy]).all() and K.fx > 0 and K.fy > 0
    assert frame.R_tilt is None or is_rotation(frame.R_tilt)


# ----------------------------------------------------------------------------- frames and images


@SETTINGS
@given(data=st.data())
def test_colour_files(tmp_path: Path, valid: dict[str, Any], data: st.DataObject) -> None:
    kind = data.draw(st.sampled_from(["color_png", "color_jpg"]))
    content = data.draw(files(valid["color.png"], valid["color.jpg"]))
    _check_frame(_frame_folder(tmp_path, valid, **{kind: content}))


@SETTINGS
@given(data=st.data())
def test_depth_files(tmp_path: Path, valid: dict[str, Any], data: st.DataObject) -> None:
    kind = data.draw(st.sampled_from(["depth_png", "depth_npy"]))
    content = data.draw(files(valid["depth.png"], valid["depth.npy"]))
    _check_frame(_frame_folder(tmp_path, valid, **{kind: content}))


@SETTINGS
@given(data=st.data())
@example(data=None)
def test_meta_files(tmp_path: Path, valid: dict[str, Any], data: st.DataObject | None) -> None:
    if data is None:  # the explicit examples
        beyond_float64 = b'{"intrinsics": {"fx": 1' + b"0" * 400 + b', "fy": 20, "cx": 7.5, "cy": 5.5}}'
        for content in (DEEP_JSON, HUGE_INTEGER, beyond_float64):
            _check_frame(_frame_folder(tmp_path, valid, meta_json=content))
        return
    _check_frame(_frame_folder(tmp_path, valid, meta_json=data.draw(json_files(valid["meta.json"]))))


@SETTINGS
@given(data=st.data())
@example(data=None)
def test_ground_truth_files(tmp_path: Path, valid: dict[str, Any], data: st.DataObject | None) -> None:
    ref = _frame_folder(tmp_path, valid)
    ref = FrameRef(ref.name, ref.color_path, ref.depth_path, ref.meta_path, gt_path=tmp_path / "f.gt.json")
    class_list = valid["gt.json"].replace(b'"class": "chair"', b'"class": ["chair"]')  # unhashable
    explicit = [DEEP_JSON, HUGE_INTEGER, class_list]
    contents = explicit if data is None else [data.draw(json_files(valid["gt.json"]))]
    for content in contents:
        ref.gt_path.write_bytes(content)
        gt = outcome(lambda: read_ground_truth(ref), ref.gt_path)
        if gt is not None:
            n = len(gt)
            boxes = (gt.boxes3d, gt.boxes2d_visible, gt.boxes2d_amodal)
            assert [b.shape for b in boxes] == [(n, 7), (n, 4), (n, 4)]
            assert all(np.isfinite(b).all() for b in boxes) and (gt.boxes3d[:, 3:6] > 0).all()
            assert ((gt.class_ids >= 0) & (gt.class_ids < NUM_CLASSES)).all()


@SETTINGS
@given(data=st.data())
def test_image_headers_match_the_decoded_image(
    tmp_path: Path, valid: dict[str, Any], data: st.DataObject
) -> None:
    """image_io's checks, then the decode: the header's size is the decoded image's size."""
    content = data.draw(files(valid["color.png"], valid["color.jpg"], valid["depth.png"]))
    path = tmp_path / "image.png"
    path.write_bytes(content)
    header = outcome(lambda: image_io.read_image_header(path), path)
    if header is None:
        return
    image = outcome(lambda: image_io.decode_image(content, path, cv2.IMREAD_UNCHANGED), path)
    if image is not None:
        assert image.shape[:2] == header.size


# ----------------------------------------------------------------------------- proposals, detections


@SETTINGS
@given(data=st.data())
def test_proposal_files(tmp_path: Path, valid: dict[str, Any], data: st.DataObject) -> None:
    path = tmp_path / "f.proposals.npz"
    path.write_bytes(data.draw(files(*valid["proposals"])))
    proposals = outcome(lambda: read_precomputed_proposals(path, (H, W)), path)
    if proposals is None:
        return
    n = len(proposals)
    assert proposals.boxes.shape == (n, 4) and np.isfinite(proposals.boxes).all()
    scores = proposals.scores
    assert scores is None or (scores.shape == (n,) and np.isfinite(scores).all())
    for i in range(n):
        assert proposals.mask(i).shape == (H, W)


def test_proposal_archives_with_corrupt_members(tmp_path: Path, valid: dict[str, Any]) -> None:
    """Zip-level damage that random edits rarely hit: garbage in a member's deflate stream, an
    unknown compression method, the "encrypted" flag. A zip with data in front of it (as a
    self-extracting archive has) is read as the zip it is, like every other reader of zips."""
    source = valid["proposals"][1]
    local = 0  # the first member's local header, and the central directory's entry for it
    central = source.index(b"PK\x01\x02")
    name_length, extra_length = struct.unpack("<HH", source[local + 26 : local + 30])
    data_start = local + 30 + name_length + extra_length
    garbage = bytearray(source)
    garbage[data_start : data_start + 8] = b"\xff" * 8
    method, encrypted = bytearray(source), bytearray(source)
    for header, offset in ((local, 0), (central, 2)):  # the central entry has one more field first
        method[header + offset + 8] = 99
        encrypted[header + offset + 6] |= 1
    for name, content in {
        "garbage_deflate": garbage,
        "unknown_method": method,
        "encrypted": encrypted,
    }.items():
        path = tmp_path / f"{name}.proposals.npz"
        path.write_bytes(bytes(content))
        with pytest.raises(InputError) as info:
            read_precomputed_proposals(path, (H, W))
        assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value), name
    (tmp_path / "plain.proposals.npz").write_bytes(source)
    (tmp_path / "prefixed.proposals.npz").write_bytes(b"\x00" * 7 + source)
    plain, prefixed = (
        read_precomputed_proposals(tmp_path / f"{n}.proposals.npz", (H, W)) for n in ("plain", "prefixed")
    )
    for key in ("boxes", "scores", "superpixels", "indptr", "indices"):
        np.testing.assert_array_equal(getattr(prefixed, key), getattr(plain, key), err_msg=key)


@SETTINGS
@given(data=st.data())
@example(data=None)
def test_detection_lines(valid: dict[str, Any], data: st.DataObject | None) -> None:
    where = "detections.jsonl:7"
    if data is None:
        texts = [
            DEEP_JSON.decode(),
            HUGE_INTEGER.decode(),
            valid["line"].replace('"score":0.9', '"score":1' + "0" * 400),
        ]
    else:
        line = valid["line"]
        mutated_text = mutated(line.encode()).map(lambda b: b.decode("utf-8", "replace"))
        texts = [data.draw(st.one_of(edited_json(json.loads(line)), mutated_text, st.text(max_size=200)))]
    for text in texts:
        det = outcome(lambda t=text: parse_line(t, where), where)
        if det is None:
            continue
        n = len(det.class_ids)
        assert det.scores.shape == (n,) and det.boxes2d.shape == (n, 4) and det.boxes3d.shape == (n, 7)
        for values in (det.scores, det.boxes2d, det.boxes3d, det.R_tilt):
            assert np.isfinite(values).all()
        assert is_rotation(det.R_tilt) and (det.boxes3d[:, 3:6] > 0).all()
        assert det.corners is None or np.isfinite(det.corners).all()
        assert all(np.isfinite(v) for v in det.timing.values())
