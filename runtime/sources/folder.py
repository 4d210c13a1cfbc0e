"""The RGB-D frame folder (README "Frame format"): list, read and validate, and write frames.

A frame ``NAME`` is ``NAME.color.{png,jpg,jpeg}`` + ``NAME.depth.{png,npy}``, optionally
``NAME.meta.json``, ``NAME.gt.json``, ``NAME.instances.png`` and ``NAME.proposals.npz`` (README
"Precomputed proposals"); the folder's ``intrinsics.json`` holds the shared intrinsics.

Units: colour is uint8 BGR (H, W, 3); depth in memory is float32 metres, 0 = missing. A depth PNG
is uint16 millimetres: writing rounds to the nearest millimetre, reading gives
``float32(mm) / 1000`` (so write(read(x)) is exact, and a round trip changes depth by at most
0.5 mm). A depth ``.npy`` is float32 metres, stored exactly. Boxes use the README's pixel
convention and the 7-vector ``[x, y, z, l, w, h, theta]`` of ``a3d.runtime.structures.geometry``.

Reading validates everything and raises ``InputError("PATH: problem")`` (one line) for: an
unreadable, empty, truncated or undecodable image; an image above ``MAX_IMAGE_SIDE`` /
``MAX_IMAGE_PIXELS`` (checked from the header, before decoding); greyscale or 16-bit colour
(the network is trained on 8-bit colour); an 8-bit or multi-channel depth PNG; a depth ``.npy``
that is not float, holds NaN/inf or negative values, or whose values look like millimetres;
colour and depth (or instances) of different sizes; malformed JSON (with line and column);
unknown keys; missing intrinsics; an ``R_tilt`` that is not a rotation; an unknown class name;
box vectors of the wrong length, non-finite or with non-positive sizes. An all-zero depth map is
readable: the frame carries a warning (``Frame.warnings``) and the front end copes with it.

Writing is atomic per file (temporary file in the same folder, then ``os.replace``), and the
colour file is written last, so an interrupted ``write_frame`` leaves a frame that
``list_frames`` reports as incomplete rather than one with mixed old and new parts.
"""

from __future__ import annotations

import io
import json
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import atomic_write_bytes
from a3d.runtime.io.image_io import (
    MAX_IMAGE_PIXELS,
    ImageHeader,
    check_complete,
    decode_image,
    parse_header,
    read_bytes,
    read_image_header,
)
from a3d.runtime.io.json_input import parse_json
from a3d.runtime.io.npy import npy_header
from a3d.runtime.sources.arrays import MILLIMETRE, depth_units_to_metres
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.proposals_file import read_precomputed_proposals
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.frame import Frame, GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, check_rotation
from a3d.runtime.structures.pose import check_pose

logger = logging.getLogger(__name__)

INTRINSICS_FILE = "intrinsics.json"
MODEL_FILE = "model.onnx"  # a3d-run's default model, kept beside the frames it was made for
LABELS_FILE = "labels.jsonl"  # a3d-labels' record of what each frame sees (docs/mapping.md)
TRACKING_FILE = "tracking.jsonl"  # a3d-poses' record of each frame's tracking (docs/mapping.md)
_FOLDER_FILES = {INTRINSICS_FILE, MODEL_FILE, LABELS_FILE, TRACKING_FILE}
COLOR_SUFFIXES = (".color.png", ".color.jpg", ".color.jpeg")
DEPTH_SUFFIXES = (".depth.png", ".depth.npy")
PROPOSALS_SUFFIX = ".proposals.npz"
# Optional per-frame files -> FrameRef field.
_OPTIONAL_SUFFIXES = {
    ".meta.json": "meta_path",
    ".gt.json": "gt_path",
    ".instances.png": "instances_path",
    PROPOSALS_SUFFIX: "proposals_path",
}
MM_PER_M = 1000.0
MAX_DEPTH_PNG_M = 65535 / MM_PER_M
"""Deepest depth a uint16 millimetre PNG can hold (65.535 m)."""
NPY_MILLIMETRE_MEDIAN = 20.0
"""A depth ``.npy`` whose median valid value is above this many "metres" is taken to be millimetres."""
PNG_METRE_MEDIAN_MM = 20.0
"""A depth PNG whose median valid value is below this many millimetres is taken to be metres."""
"""Most proposals accepted in a ``.proposals.npz`` file."""
_INTRINSICS_KEYS = ("fx", "fy", "cx", "cy")
_META_KEYS = ("intrinsics", "R_tilt", "pose")
_OBJECT_KEYS = ("class", "box3d", "box2d_visible", "box2d_amodal", "instance")
_COLOR_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION  # EXIF rotation would break registration


@dataclass(frozen=True)
class FrameRef:
    """The files of one frame; optional ones are None when absent."""

    name: str
    color_path: Path
    depth_path: Path
    meta_path: Path | None = None
    gt_path: Path | None = None
    instances_path: Path | None = None
    proposals_path: Path | None = None


@dataclass(frozen=True)
class SkippedFile:
    """A file of the folder that is not part of any complete frame, and why; ``frame`` is the
    NAME of the frame it was meant for ("" for a file of no frame: notes, the model, a folder)."""

    path: Path
    reason: str
    frame: str = ""


@dataclass(frozen=True)
class FolderListing:
    """What ``scan_folder`` found: complete frames (sorted by name) and the files it skipped."""

    frames: list[FrameRef]
    skipped: list[SkippedFile]


@dataclass(frozen=True)
class FrameMeta:
    """``NAME.meta.json``: a per-frame intrinsics override, gravity and camera pose, each optional.
    A pose that is no rigid transform does not fail the frame: ``pose_problem`` says what is wrong
    and the frame is read without a pose (its line notes it)."""

    intrinsics: Intrinsics | None = None
    R_tilt: np.ndarray | None = None  # (3, 3) p_tilt = R_tilt p_cam
    pose: np.ndarray | None = None  # (4, 4) camera-to-world, metres
    pose_problem: str = ""


# ----------------------------------------------------------------------------- listing


def scan_folder(folder: str | os.PathLike) -> FolderListing:
    """Group the folder's files into frames; files that fit no complete frame are listed as skipped."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {'not a folder' if folder.exists() else 'no such folder'}")
    parts: dict[str, dict[str, list[Path]]] = {}
    skipped: list[SkippedFile] = []
    for entry in sorted(os.scandir(folder), key=lambda e: e.name):
        path = Path(entry.path)
        if entry.name.startswith(".") or entry.name in _FOLDER_FILES:
            continue
        if entry.is_dir():
            skipped.append(SkippedFile(path, "a folder (frames are not searched for in sub-folders)"))
            continue
        role, name = _role_of(entry.name)
        if role is None or not name:
            skipped.append(_unknown_file(path))
            continue
        parts.setdefault(name, {}).setdefault(role, []).append(path)
    frames: list[FrameRef] = []
    for name in sorted(parts):
        roles = parts[name]
        problem = _incomplete(roles)
        if problem:
            skipped.extend(SkippedFile(p, problem, name) for paths in roles.values() for p in paths)
            continue
        optional = {
            field_: roles[suffix][0] for suffix, field_ in _OPTIONAL_SUFFIXES.items() if suffix in roles
        }
        frames.append(FrameRef(name, roles["color"][0], roles["depth"][0], **optional))
    return FolderListing(frames, skipped)


def list_frames(folder: str | os.PathLike) -> list[FrameRef]:
    """Complete frames of a folder, sorted by name; skipped files are logged as warnings."""
    listing = scan_folder(folder)
    for item in listing.skipped:
        logger.warning("%s: skipped: %s", item.path, item.reason)
    return listing.frames


def _role_of(filename: str) -> tuple[str | None, str]:
    lower = filename.lower()
    for role, suffixes in (("color", COLOR_SUFFIXES), ("depth", DEPTH_SUFFIXES)):
        for suffix in suffixes:
            if lower.endswith(suffix):
                return role, filename[: -len(suffix)]
    for suffix in _OPTIONAL_SUFFIXES:
        if lower.endswith(suffix):
            return suffix, filename[: -len(suffix)]
    return None, ""


def _unknown_file(path: Path) -> SkippedFile:
    """A file of no known type; named like a frame's colour or depth file (``NAME.color.bmp``),
    it is that frame's, in a format a3d does not read."""
    stem, _, extension = path.name.rpartition(".")
    for role, suffixes in (("color", COLOR_SUFFIXES), ("depth", DEPTH_SUFFIXES)):
        name = stem[: -len(role) - 1]
        if name and stem.lower().endswith(f".{role}"):
            reason = f"unsupported {role} file type .{extension} (expected {', '.join(suffixes)})"
            return SkippedFile(path, reason, name)
    return SkippedFile(path, "unknown file type")


def _incomplete(roles: dict[str, list[Path]]) -> str:
    for role in ("color", "depth"):
        if role not in roles:
            return f"frame has no {role} file"
    for paths in roles.values():
        if len(paths) > 1:
            return f"ambiguous frame: {' and '.join(p.name for p in paths)}"
    return ""


# ----------------------------------------------------------------------------- reading


def read_folder_intrinsics(folder: str | os.PathLike) -> Intrinsics | None:
    """The folder's ``intrinsics.json``, or None if it has none."""
    path = Path(folder) / INTRINSICS_FILE
    if not path.exists():
        return None
    return _parse_intrinsics(_load_json(path), path, "intrinsics")


def read_frame(ref: FrameRef, folder_intrinsics: Intrinsics | None, *, with_proposals: bool = False) -> Frame:
    """Read and validate one frame (see the module docstring for what is checked); with
    ``with_proposals``, its ``NAME.proposals.npz`` too where it has one."""
    color_data, color_header = read_color_bytes(ref.color_path)
    depth_size, load_depth = _open_depth(ref.depth_path)
    if depth_size != color_header.size:
        raise InputError(
            f"{ref.depth_path}: depth is {depth_size[0]}x{depth_size[1]} "
            f"but colour is {color_header.height}x{color_header.width}"
        )
    meta = read_meta(ref)
    intrinsics = meta.intrinsics or folder_intrinsics
    if intrinsics is None:
        raise InputError(
            f"{ref.color_path.parent / INTRINSICS_FILE}: missing, and {ref.name}.meta.json has no intrinsics"
        )
    color = decode_image(color_data, ref.color_path, _COLOR_FLAGS)
    depth = load_depth()
    warnings: tuple[str, ...] = ()
    pose_note = ""
    if meta.pose_problem:
        pose_note = f"no pose: {meta.pose_problem}"
        logger.warning("%s (the frame is processed without a pose)", meta.pose_problem)
    if not depth.any():
        warnings = (f"{ref.depth_path}: depth has no valid pixels (all zero)",)
        logger.warning(warnings[0])
    proposals = None
    if with_proposals and ref.proposals_path is not None:
        proposals = read_precomputed_proposals(ref.proposals_path, depth.shape)
    return Frame(
        ref.name,
        color,
        depth,
        intrinsics,
        meta.R_tilt,
        origin=str(ref.color_path),
        color_file=str(ref.color_path),
        depth_file=str(ref.depth_path),
        proposals=proposals,
        warnings=warnings,
        pose=meta.pose,
        pose_note=pose_note,
    )


def read_ground_truth(ref: FrameRef) -> GroundTruth | None:
    """The frame's ``NAME.gt.json``, validated, or None if it has none."""
    if ref.gt_path is None:
        return None
    path = ref.gt_path
    if read_meta(ref).R_tilt is None:
        raise InputError(
            f"{path}: ground truth needs R_tilt in {ref.name}.meta.json (theta is in the tilt frame)"
        )
    document = _load_json(path)
    if not isinstance(document, dict) or not isinstance(document.get("objects"), list):
        raise InputError(f'{path}: expected an object {{"objects": [...]}}')
    _no_unknown_keys(document, ("objects",), path, "top level")
    rows = [_parse_object(obj, path, f"objects[{i}]") for i, obj in enumerate(document["objects"])]
    return GroundTruth.from_classes(
        [r[0] for r in rows],
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows],
        [r[4] for r in rows],
    )


def read_instances(ref: FrameRef) -> np.ndarray | None:
    """The frame's visible-instance map (H, W) uint16, or None if it has none."""
    if ref.instances_path is None:
        return None
    path = ref.instances_path
    data = read_bytes(path)
    header = parse_header(data, path)
    if header.kind != "png" or header.channels != 1 or header.bit_depth not in (8, 16):
        raise InputError(f"{path}: instance map must be a 1-channel 16-bit PNG ({_describe(header)})")
    check_complete(data, header, path)
    color_size = read_image_header(ref.color_path).size
    if header.size != color_size:
        raise InputError(
            f"{path}: instance map is {header.height}x{header.width} "
            f"but colour is {color_size[0]}x{color_size[1]}"
        )
    return decode_image(data, path, cv2.IMREAD_UNCHANGED).astype(np.uint16)


def read_color(path: Path) -> np.ndarray:
    """A colour image file as uint8 BGR (H, W, 3), checked as ``read_color_bytes`` checks it."""
    data, _ = read_color_bytes(path)
    return decode_image(data, path, _COLOR_FLAGS)


def read_color_bytes(path: Path) -> tuple[bytes, ImageHeader]:
    """A colour image file's bytes and header, checked (8-bit colour, size limit, complete), not decoded."""
    data = read_bytes(path)
    header = parse_header(data, path)
    if header.channels in (1, 2):
        raise InputError(f"{path}: colour image is greyscale; a3d needs 3-channel colour (8-bit)")
    if header.bit_depth != 8 and not (header.kind == "png" and header.channels == 3 and header.bit_depth < 8):
        raise InputError(f"{path}: colour image is {header.bit_depth}-bit per channel; expected 8-bit")
    check_complete(data, header, path)
    return data, header


def _open_depth(path: Path) -> tuple[tuple[int, int], Callable[[], np.ndarray]]:
    """(height, width) from the depth file's header, and a function that loads it as metres."""
    if path.name.lower().endswith(".npy"):
        return _open_depth_npy(path)
    data = read_bytes(path)
    header = parse_header(data, path)
    if header.kind != "png":
        raise InputError(f"{path}: depth must be a 16-bit PNG, this is a JPEG")
    if header.channels != 1:
        raise InputError(f"{path}: depth PNG has {header.channels} channels; expected 1 (uint16 millimetres)")
    if header.bit_depth != 16:
        raise InputError(
            f"{path}: depth PNG is {header.bit_depth}-bit; expected 16-bit millimetres (0 = missing)"
        )
    check_complete(data, header, path)

    def load() -> np.ndarray:
        millimetres = decode_image(data, path, cv2.IMREAD_UNCHANGED)
        valid = millimetres[millimetres > 0]
        if valid.size and np.median(valid) < PNG_METRE_MEDIAN_MM:
            raise InputError(
                f"{path}: depth values look like metres, not millimetres "
                f"(median valid value {np.median(valid):g}); a depth PNG holds uint16 millimetres"
            )
        return depth_units_to_metres(millimetres, MILLIMETRE)

    return header.size, load


def _open_depth_npy(path: Path) -> tuple[tuple[int, int], Callable[[], np.ndarray]]:
    try:
        with open(path, "rb") as f:
            shape, dtype, offset = npy_header(f, path)
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
    if len(shape) != 2:
        raise InputError(f"{path}: depth .npy has shape {shape}; expected (H, W)")
    if dtype.kind != "f":
        raise InputError(
            f"{path}: depth .npy is {dtype}; expected float32 metres (millimetre integers go in a .depth.png)"
        )
    if shape[0] * shape[1] > MAX_IMAGE_PIXELS or min(shape) <= 0:
        raise InputError(
            f"{path}: depth is {shape[0]}x{shape[1]}, outside the limit of {MAX_IMAGE_PIXELS} pixels"
        )
    needed = offset + shape[0] * shape[1] * dtype.itemsize
    if path.stat().st_size < needed:
        raise InputError(f"{path}: .npy is truncated (needs {needed} bytes, file has {path.stat().st_size})")

    def load() -> np.ndarray:
        depth = np.load(path, allow_pickle=False).astype(np.float32)
        bad = int(np.count_nonzero(~np.isfinite(depth)))
        if bad:
            raise InputError(f"{path}: depth has {bad} NaN/inf values; use 0 for missing depth")
        negative = int(np.count_nonzero(depth < 0))
        if negative:
            raise InputError(f"{path}: depth has {negative} negative values")
        valid = depth[depth > 0]
        if valid.size and np.median(valid) > NPY_MILLIMETRE_MEDIAN:
            raise InputError(
                f"{path}: depth values look like millimetres (median valid value {np.median(valid):g}); "
                "a depth .npy holds float32 metres"
            )
        return depth

    return (shape[0], shape[1]), load


def read_meta(ref: FrameRef) -> FrameMeta:
    """The frame's ``NAME.meta.json``, validated (every field None when the frame has none)."""
    if ref.meta_path is None:
        return FrameMeta()
    path = ref.meta_path
    document = _load_json(path)
    if not isinstance(document, dict):
        raise InputError(f"{path}: expected a JSON object")
    _no_unknown_keys(document, _META_KEYS, path, "top level")
    intrinsics = None
    if document.get("intrinsics") is not None:
        intrinsics = _parse_intrinsics(document["intrinsics"], path, "intrinsics")
    R_tilt = None
    if document.get("R_tilt") is not None:
        R_tilt = check_rotation(_numbers(document["R_tilt"], (3, 3), path, "R_tilt"), f"{path}: R_tilt")
    pose, pose_problem = None, ""
    if document.get("pose") is not None:
        try:
            pose = check_pose(_numbers(document["pose"], (4, 4), path, "pose"), f"{path}: pose")
        except InputError as e:
            pose_problem = str(e)
    return FrameMeta(intrinsics, R_tilt, pose, pose_problem)


def _parse_intrinsics(value: Any, path: Path, what: str) -> Intrinsics:
    if not isinstance(value, dict):
        raise InputError(f'{path}: {what} must be an object {{"fx": .., "fy": .., "cx": .., "cy": ..}}')
    _no_unknown_keys(value, _INTRINSICS_KEYS, path, what)
    missing = [key for key in _INTRINSICS_KEYS if key not in value]
    if missing:
        raise InputError(f"{path}: {what} lacks {', '.join(missing)}")
    fx, fy, cx, cy = (float(_numbers(value[key], (), path, f"{what}.{key}")) for key in _INTRINSICS_KEYS)
    if fx <= 0 or fy <= 0:
        raise InputError(f"{path}: {what} focal lengths must be positive (fx {fx:g}, fy {fy:g})")
    return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy)


def _parse_object(obj: Any, path: Path, what: str) -> tuple[str, np.ndarray, np.ndarray, np.ndarray, int]:
    if not isinstance(obj, dict):
        raise InputError(f"{path}: {what} must be an object")
    _no_unknown_keys(obj, _OBJECT_KEYS, path, what)
    missing = [key for key in _OBJECT_KEYS[:4] if key not in obj]
    if missing:
        raise InputError(f"{path}: {what} lacks {', '.join(missing)}")
    name = obj["class"]
    if not isinstance(name, str) or name not in CLASSES:
        raise InputError(f"{path}: {what}.class {name!r} is not one of the 19 classes ({', '.join(CLASSES)})")
    box3d = _numbers(obj["box3d"], (BOX_DIM,), path, f"{what}.box3d")
    if not (box3d[3:6] > 0).all():
        raise InputError(f"{path}: {what}.box3d sizes l, w, h must be positive, got {box3d[3:6].tolist()}")
    boxes2d = [_box2d(obj[key], path, f"{what}.{key}") for key in ("box2d_visible", "box2d_amodal")]
    instance = obj.get("instance", 0)
    if isinstance(instance, bool) or not isinstance(instance, int) or not 0 <= instance <= 65535:
        raise InputError(f"{path}: {what}.instance must be an integer in [0, 65535], got {instance!r}")
    return name, box3d, boxes2d[0], boxes2d[1], instance


def _box2d(value: Any, path: Path, what: str) -> np.ndarray:
    box = _numbers(value, (4,), path, what)
    if box[2] < box[0] or box[3] < box[1]:
        raise InputError(
            f"{path}: {what} must be [x1, y1, x2, y2] with x2 >= x1 and y2 >= y1, got {box.tolist()}"
        )
    return box


def _numbers(value: Any, shape: tuple[int, ...], path: Path, what: str) -> np.ndarray:
    """A JSON number or nested list as float64 of exactly ``shape``, all finite."""
    expected = "a number" if not shape else f"{'x'.join(map(str, shape))} numbers"

    def flat(v: Any, depth: int) -> list[Any]:
        if depth == len(shape):
            return [v]
        if not isinstance(v, list) or len(v) != shape[depth]:
            raise InputError(f"{path}: {what} must be {expected}, got {_preview(value)}")
        return [x for item in v for x in flat(item, depth + 1)]

    items = flat(value, 0)
    if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in items):
        raise InputError(f"{path}: {what} must be {expected}, got {_preview(value)}")
    try:
        array = np.array(items, dtype=np.float64).reshape(shape)
    except OverflowError:  # a JSON integer beyond float64
        array = np.full(shape, np.inf)
    if not np.isfinite(array).all():
        raise InputError(f"{path}: {what} has a non-finite value ({_preview(value)})")
    return array


def _preview(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _no_unknown_keys(document: dict, known: Sequence[str], path: Path, what: str) -> None:
    unknown = [key for key in document if key not in known]
    if unknown:
        raise InputError(f"{path}: {what} has unknown key {unknown[0]!r} (expected: {', '.join(known)})")


def _load_json(path: Path) -> Any:
    return parse_json(read_bytes(path), str(path))


def _describe(header: ImageHeader) -> str:
    return f"this is a {header.bit_depth}-bit {header.kind.upper()} with {header.channels} channel(s)"


# ----------------------------------------------------------------------------- writing


def write_intrinsics(folder: str | os.PathLike, K: Intrinsics) -> Path:
    """Write the folder's ``intrinsics.json`` (atomically); returns its path."""
    path = Path(folder) / INTRINSICS_FILE
    atomic_write_bytes(path, _json_bytes(_intrinsics_dict(K)))
    return path


def write_frame(
    folder: str | os.PathLike,
    name: str,
    color: np.ndarray | bytes,
    depth_m: np.ndarray,
    *,
    R_tilt: np.ndarray | None = None,
    intrinsics_override: Intrinsics | None = None,
    gt: GroundTruth | None = None,
    instances: np.ndarray | None = None,
    depth_format: str = "png",
    pose: np.ndarray | None = None,
) -> FrameRef:
    """Write one frame into ``folder`` (created if needed) and return its FrameRef.

    ``color`` is uint8 BGR (H, W, 3), written as PNG, or the bytes of an encoded 8-bit colour
    PNG/JPEG, written unchanged (e.g. a source JPEG, to avoid re-compressing it). ``depth_m`` is
    (H, W) metres, 0 = missing; ``depth_format`` "png" (uint16 millimetres, rounded to the
    nearest millimetre, at most ``MAX_DEPTH_PNG_M``) or "npy" (float32 metres). Ground truth
    needs ``R_tilt``. ``pose`` (4, 4) camera-to-world goes into ``NAME.meta.json`` (checked rigid).
    Each file is written atomically; an earlier colour file of this frame is
    removed first and the new one written last, so an interrupted write leaves an incomplete
    frame (skipped by ``list_frames``), never a mix. Files of this frame in another format, or
    optional files not given now, are removed (``NAME.proposals.npz`` is left alone). Bad
    arguments raise ValueError, before anything is written.
    """
    folder = Path(folder)
    if not name or name.startswith(".") or Path(name).name != name:
        raise ValueError(f"frame name {name!r} must be a plain file-name stem")
    if depth_format not in ("png", "npy"):
        raise ValueError(f"depth_format must be 'png' or 'npy', got {depth_format!r}")
    color_suffix, color_bytes, size = _encode_color(color)
    depth = np.asarray(depth_m)
    if depth.shape != size:
        raise ValueError(f"depth is {'x'.join(map(str, depth.shape))} but colour is {size[0]}x{size[1]}")
    depth_bytes = _encode_depth(depth, depth_format)
    files: dict[str, bytes] = {f".depth.{depth_format}": depth_bytes, color_suffix: color_bytes}
    if R_tilt is not None or intrinsics_override is not None or pose is not None:
        meta: dict[str, Any] = {}
        if intrinsics_override is not None:
            meta["intrinsics"] = _intrinsics_dict(intrinsics_override)
        if R_tilt is not None:
            meta["R_tilt"] = check_rotation(np.asarray(R_tilt, dtype=np.float64), "R_tilt").tolist()
        if pose is not None:
            meta["pose"] = check_pose(pose, "pose").tolist()
        files[".meta.json"] = _json_bytes(meta)
    if gt is not None:
        if R_tilt is None:
            raise ValueError("ground truth needs R_tilt (its theta is measured in the tilt frame)")
        files[".gt.json"] = _json_bytes({"objects": _gt_objects(gt)})
    if instances is not None:
        files[".instances.png"] = _encode_instances(instances, size)
    # The old colour goes first and the new one comes last: until the write completes, the frame
    # has no colour file and is listed as incomplete, never as a mix of old and new files.
    for suffix in (*COLOR_SUFFIXES, *DEPTH_SUFFIXES, ".meta.json", ".gt.json", ".instances.png"):
        if suffix not in files or suffix == color_suffix:
            (folder / f"{name}{suffix}").unlink(missing_ok=True)
    for suffix in sorted(files, key=lambda s: s == color_suffix):
        atomic_write_bytes(folder / f"{name}{suffix}", files[suffix])
    return FrameRef(
        name,
        folder / f"{name}{color_suffix}",
        folder / f"{name}.depth.{depth_format}",
        meta_path=folder / f"{name}.meta.json" if ".meta.json" in files else None,
        gt_path=folder / f"{name}.gt.json" if gt is not None else None,
        instances_path=folder / f"{name}.instances.png" if instances is not None else None,
        proposals_path=_existing(folder / f"{name}{PROPOSALS_SUFFIX}"),
    )


def _encode_color(color: np.ndarray | bytes) -> tuple[str, bytes, tuple[int, int]]:
    if isinstance(color, (bytes, bytearray)):
        data = bytes(color)
        header = parse_header(data, Path("<colour bytes>"))
        if header.channels not in (3, 4) or header.bit_depth > 8:
            raise ValueError(f"colour bytes must be an 8-bit colour image ({_describe(header)})")
        check_complete(data, header, Path("<colour bytes>"))
        return (".color.png" if header.kind == "png" else ".color.jpg"), data, header.size
    image = np.asarray(color)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"colour must be uint8 (H, W, 3) BGR, got {image.dtype} {image.shape}")
    return ".color.png", _png_bytes(image), (image.shape[0], image.shape[1])


def _encode_depth(depth: np.ndarray, depth_format: str) -> bytes:
    if depth.ndim != 2 or depth.dtype.kind != "f":
        raise ValueError(f"depth must be a float (H, W) array in metres, got {depth.dtype} {depth.shape}")
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise ValueError("depth must be finite and >= 0 (0 = missing)")
    if depth_format == "npy":
        buffer = io.BytesIO()
        np.save(buffer, depth.astype(np.float32), allow_pickle=False)
        return buffer.getvalue()
    millimetres = np.rint(depth.astype(np.float64) * MM_PER_M)
    if millimetres.max(initial=0) > 65535:
        raise ValueError(
            f"depth up to {depth.max():g} m does not fit a millimetre PNG (max {MAX_DEPTH_PNG_M} m)"
        )
    return _png_bytes(millimetres.astype(np.uint16))


def _encode_instances(instances: np.ndarray, size: tuple[int, int]) -> bytes:
    array = np.asarray(instances)
    if (
        array.shape != size
        or array.dtype.kind not in "ui"
        or array.min(initial=0) < 0
        or array.max(initial=0) > 65535
    ):
        raise ValueError(f"instances must be a (H, W) = {size} integer map with values in [0, 65535]")
    return _png_bytes(array.astype(np.uint16))


def _gt_objects(gt: GroundTruth) -> list[dict[str, Any]]:
    if not (np.isfinite(gt.boxes3d).all() and np.isfinite(gt.boxes2d_visible).all()):
        raise ValueError("ground-truth boxes must be finite")
    return [
        {"class": name, "box3d": b3, "box2d_visible": bv, "box2d_amodal": ba, "instance": int(k)}
        for name, b3, bv, ba, k in zip(
            gt.classes,
            np.asarray(gt.boxes3d, np.float64).tolist(),
            np.asarray(gt.boxes2d_visible, np.float64).tolist(),
            np.asarray(gt.boxes2d_amodal, np.float64).tolist(),
            gt.instance_ids,
            strict=True,
        )
    ]


def _intrinsics_dict(K: Intrinsics) -> dict[str, float]:
    return {key: float(getattr(K, key)) for key in _INTRINSICS_KEYS}


def _json_bytes(document: dict[str, Any]) -> bytes:
    """One key per line, and one line per element of a list of objects (readable, diffable)."""

    def value(v: Any) -> str:
        if isinstance(v, list) and v and all(isinstance(item, dict) for item in v):
            return "[\n  " + ",\n  ".join(json.dumps(item, allow_nan=False) for item in v) + "\n ]"
        return json.dumps(v, allow_nan=False)

    body = ",\n".join(f" {json.dumps(key)}: {value(v)}" for key, v in document.items())
    return ("{\n" + body + "\n}\n").encode("utf-8")


def _png_bytes(image: np.ndarray) -> bytes:
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError(f"cannot encode a {image.dtype} {image.shape} array as PNG")
    return encoded.tobytes()


def _existing(path: Path) -> Path | None:
    return path if path.exists() else None


# ----------------------------------------------------------------------------- as a frame source


class FolderSource:
    """An a3d frame folder as a frame source: its complete frames, sorted by name.

    ``incomplete`` lists one "PATH: reason" per frame that cannot be read (named by its first
    skipped file); files of no frame (the model, notes, sub-folders) are no problem. With
    ``with_proposals`` a frame brings its ``NAME.proposals.npz``; with ``with_truth`` its ground
    truth (a bad ``NAME.gt.json`` then costs the frame only its ground truth, with a warning).
    """

    depth_scale = MILLIMETRE  # a depth PNG's unit (--depth-scale replaces it; .npy depth is metres)

    def __init__(self, folder: str | os.PathLike, *, with_proposals: bool = True, with_truth: bool = False):
        listing = scan_folder(folder)
        self.folder = Path(folder)
        self.refs = listing.frames
        first: dict[str, SkippedFile] = {}
        for item in listing.skipped:
            if item.frame:
                first.setdefault(item.frame, item)
        self.incomplete = [f"{item.path}: {item.reason}" for item in first.values()]
        self.intrinsics = read_folder_intrinsics(folder)
        self.with_proposals = with_proposals
        self.with_truth = with_truth

    def __iter__(self) -> Iterator[FrameLoader]:
        return (self.loader(ref) for ref in self.refs)

    @property
    def has_poses(self) -> bool:
        """Whether the folder is posed: its first frame's meta.json gives a pose (a bad one too)."""
        try:
            meta = read_meta(self.refs[0]) if self.refs else FrameMeta()
        except InputError:
            return False
        return meta.pose is not None or bool(meta.pose_problem)

    def __len__(self) -> int:
        return len(self.refs)

    def loader(self, ref: FrameRef) -> FrameLoader:
        files = [getattr(ref, f.name) for f in fields(ref) if f.name.endswith("_path")]
        files.append(self.folder / INTRINSICS_FILE)
        named = tuple(str(path) for path in files if path is not None)
        return FrameLoader(ref.name, str(ref.color_path), lambda: self.read(ref), named)

    def read(self, ref: FrameRef) -> Frame:
        frame = read_frame(ref, self.intrinsics, with_proposals=self.with_proposals)
        if not self.with_truth or ref.gt_path is None:
            return frame
        try:
            return replace(frame, truth=read_ground_truth(ref))
        except InputError as e:
            logger.warning("%s (ground truth not used)", e)
            return frame
