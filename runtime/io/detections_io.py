"""The detections file (README "Detections format"): one JSON line per frame, validated on read.

``a3d-run`` writes it and ``a3d-eval`` reads it. A line::

    {"frame": "NAME", "color": "path", "depth": "path", "R_tilt": [[3x3]],
     "detections": [{"class": "chair", "score": 0.93, "box2d": [x1, y1, x2, y2],
                     "box2d_amodal": [x1, y1, x2, y2], "box3d": [x, y, z, l, w, h, theta],
                     "corners": [[x, y, z], ... 8 ...]}],
     "timing": {"stage": seconds, ...},
     "gravity": "estimated", "notes": ["..."]}

``box3d`` is in the camera frame (metres) with ``theta`` in the tilt frame of the line's
``R_tilt``; ``corners`` are its 8 corners in the camera frame (``geometry.box_corners_camera``),
written for other tools' convenience. Reading requires ``frame``, ``R_tilt`` (a proper rotation)
and ``detections`` (each with a known class, a finite score, ``box2d`` with x2 >= x1 and y2 >= y1,
and ``box3d`` with positive sizes); ``color``, ``depth``, ``corners`` and ``timing`` are optional
(scoring uses ``box3d`` and ``R_tilt`` only). ``box2d_amodal`` (optional, all detections or
none) is the amodal 2D box from the network's 2D regressor, clipped to the image. Blank lines
are skipped; a frame may appear once.

``gravity`` (optional; lines from before it have none) says where the line's R_tilt came from:
"given" (the frame's own), "estimated" (from the depth) or "fallback: <method> (<reason>)"
(a3d.runtime.frontend.gravity.choose_gravity). ``notes`` (optional, a list of strings) says what
else degraded on the frame: depth mostly missing, no proposals, boxes clamped
(a3d.runtime.postprocess.box_limits); an absent list means nothing did.
``pose`` (optional) is the frame's 4 x 4 camera-to-world pose where its source has one
(docs/sources.md "Camera poses"), written exactly; it is what places the line's boxes in the world
(a3d.runtime.mapping). ``source`` (optional, per detection, all or none; written by runs with
a 2D detector) says where the detection's class came from: the detector's name, "network" (a3d's
own proposals and classifier) or both joined by "+" (a3d.runtime.postprocess.fuse). Every problem
is an ``InputError`` "FILE:LINE: what is wrong".
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import numpy as np
import orjson

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.json_input import is_finite_number, parse_json
from a3d.runtime.structures.boxes import BOX_DIM, SIZE
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.geometry import Intrinsics, box_corners_camera, check_rotation
from a3d.runtime.structures.pose import check_pose

if TYPE_CHECKING:
    import rerun as rr

_CLASS_INDEX = {name: i for i, name in enumerate(CLASSES)}
METRE_DECIMALS = 6  # box3d and corners are written to 1 micrometre
PIXEL_DECIMALS = 4  # box2d and box2d_amodal to 1e-4 pixel


@dataclass(frozen=True)
class Detection:
    """One detected object: ``result[i]`` or an item of ``for d in result``."""

    class_name: str
    class_id: int  # 0-based CLASSES index
    score: float
    box2d: np.ndarray  # (4,) [x1, y1, x2, y2], the proposal box it was scored on
    box3d: np.ndarray  # (7,) [x, y, z, l, w, h, theta], camera frame, theta in the tilt frame
    corners: np.ndarray  # (8, 3) camera frame
    box2d_amodal: np.ndarray | None = None  # (4,) the regressed amodal 2D box, when the line has it
    source: str | None = None  # where its class came from: a 2D detector, "network" or both

    def to_dict(self) -> dict[str, Any]:
        """The detection as a detections line holds it (README "Detections format"), unrounded."""
        extra = {} if self.box2d_amodal is None else {"box2d_amodal": self.box2d_amodal.tolist()}
        source = {} if self.source is None else {"source": self.source}
        return {"class": self.class_name, "score": self.score, "box2d": self.box2d.tolist(), **extra,
                "box3d": self.box3d.tolist(), "corners": self.corners.tolist(), **source}  # fmt: skip


@dataclass(frozen=True)
class FrameDetections:
    """One frame's detections (one line of the detections file), as arrays.

    A sequence of ``Detection``: ``len(result)``, ``for d in result``, ``result[i]``, and
    ``result[mask]`` / ``result[indices]`` / ``result[a:b]`` for a ``FrameDetections`` of those
    (``result[result.scores >= 0.7]``). ``to_json`` is the line, ``to_list`` its detections as
    dicts, ``draw`` an annotated image, ``log`` the 3D boxes to rerun.
    """

    frame: str
    R_tilt: np.ndarray  # (3, 3), p_tilt = R_tilt p_cam
    class_ids: np.ndarray  # (N,) int64, 0-based CLASSES index
    scores: np.ndarray  # (N,) float64
    boxes2d: np.ndarray  # (N, 4) [x1, y1, x2, y2], README pixel convention
    boxes3d: np.ndarray  # (N, 7) [x, y, z, l, w, h, theta], camera frame, theta in the R_tilt frame
    corners: np.ndarray | None = None  # (N, 8, 3) camera frame; computed from boxes3d on write if None
    color: str | None = None
    depth: str | None = None
    timing: dict[str, float] = field(default_factory=dict)
    boxes2d_amodal: np.ndarray | None = None  # (N, 4) amodal 2D boxes (2D regressor), optional
    gravity: str | None = None  # "given", "estimated" or "fallback: ..."; None in older lines
    notes: tuple[str, ...] = ()  # what degraded on this frame, one sentence each
    intrinsics: Intrinsics | None = None  # the frame's camera, for drawing (not part of the line)
    pose: np.ndarray | None = None  # (4, 4) camera-to-world where the frame has a pose
    sources: tuple[str, ...] | None = None  # per detection, with a 2D detector: a3d.runtime.postprocess.fuse

    @property
    def classes(self) -> list[str]:
        return [CLASSES[i] for i in self.class_ids]

    @property
    def box_corners(self) -> np.ndarray:
        """(N, 8, 3) corners in the camera frame (geometry's corner order)."""
        return self.corners if self.corners is not None else box_corners_camera(self.boxes3d, self.R_tilt)

    def __len__(self) -> int:
        return len(self.class_ids)

    def __iter__(self) -> Iterator[Detection]:
        return (self[i] for i in range(len(self)))

    @overload
    def __getitem__(self, index: int) -> Detection: ...

    @overload
    def __getitem__(self, index: slice | np.ndarray | list[int]) -> FrameDetections: ...

    def __getitem__(self, index: Any) -> Detection | FrameDetections:
        if isinstance(index, (int, np.integer)):
            i = range(len(self))[index]  # IndexError beyond the end, negative indices from it
            amodal = None if self.boxes2d_amodal is None else self.boxes2d_amodal[i]
            source = None if self.sources is None else self.sources[i]
            return Detection(CLASSES[self.class_ids[i]], int(self.class_ids[i]), float(self.scores[i]),
                             self.boxes2d[i], self.boxes3d[i], self.box_corners[i], amodal,
                             source)  # fmt: skip
        rows = np.arange(len(self))[index]
        if rows.ndim != 1:
            raise IndexError(f"detections: expected an int, slice, mask or indices, got {index!r:.60}")
        return replace(
            self,
            class_ids=self.class_ids[rows],
            scores=self.scores[rows],
            boxes2d=self.boxes2d[rows],
            boxes3d=self.boxes3d[rows],
            corners=None if self.corners is None else self.corners[rows],
            boxes2d_amodal=None if self.boxes2d_amodal is None else self.boxes2d_amodal[rows],
            sources=None if self.sources is None else tuple(self.sources[i] for i in rows),
        )

    def to_json(self) -> str:
        """The frame's detections line, exactly as a3d-run writes it (no trailing newline)."""
        return format_line(self)

    def to_list(self) -> list[dict[str, Any]]:
        """The detections as dicts, the line's ``"detections"`` (README "Detections format")."""
        return [d.to_dict() for d in self]

    def draw(self, image: np.ndarray, *, bgr: bool = False, boxes3d: bool = True) -> np.ndarray:
        """A copy of ``image`` (RGB, or BGR with ``bgr``) with each 2D box, its label "class score"
        and, where the camera is known, its projected 3D box, in the viewer's class colours."""
        from a3d.runtime.viewer.draw import draw_detections

        camera = {"boxes3d": self.boxes3d, "R_tilt": self.R_tilt, "K": self.intrinsics} if boxes3d else {}
        return draw_detections(image, self.class_ids, self.scores, self.boxes2d, bgr=bgr, **camera)

    def log(self, entity_path: str = "world/detections", recording: rr.RecordingStream | None = None) -> None:
        """Log the 3D boxes to rerun (the recording, or rerun's current one) as a3d-run's view does:
        in the gravity-aligned world frame, labelled and coloured by class. Needs the 'view' extra."""
        from a3d.runtime.viewer.options import load_view

        view = load_view(caller="FrameDetections.log")
        view.log_detections(recording, entity_path, class_ids=self.class_ids, scores=self.scores,
                            boxes3d=self.boxes3d, R_tilt=self.R_tilt)  # fmt: skip


def format_line(det: FrameDetections) -> str:
    """The JSON line of one frame (no trailing newline).

    Box coordinates are rounded to ``METRE_DECIMALS`` (1 micrometre) and ``PIXEL_DECIMALS``,
    far below any detector's precision: the file is about half the size and quicker to write
    and read (1.24 M detections, the NYUv2 test set at 1900 a frame, are ~0.5 GB). Scores and
    R_tilt are written exactly, so a line's gravity compares equal to the one it came from.
    orjson writes the text: the same numbers as the json module (the shortest repr of each
    float), several times faster on lines of hundreds of detections, where printing the floats
    was most of a line's cost.
    """
    corners = det.corners if det.corners is not None else box_corners_camera(det.boxes3d, det.R_tilt)
    line: dict = {"frame": det.frame}
    if det.color is not None:
        line["color"] = det.color
    if det.depth is not None:
        line["depth"] = det.depth
    line["R_tilt"] = np.asarray(det.R_tilt, dtype=np.float64).tolist()
    if det.pose is not None:
        line["pose"] = np.asarray(det.pose, dtype=np.float64).tolist()
    amodal = (
        [None] * len(det.class_ids)
        if det.boxes2d_amodal is None
        else _rounded(det.boxes2d_amodal, (-1, 4), PIXEL_DECIMALS)
    )
    sources = [None] * len(det.class_ids) if det.sources is None else det.sources
    line["detections"] = [
        {
            "class": CLASSES[c],
            "score": s,
            "box2d": b2,
            **({} if a is None else {"box2d_amodal": a}),
            "box3d": b3,
            "corners": cn,
            **({} if src is None else {"source": src}),
        }
        for c, s, b2, a, b3, cn, src in zip(
            det.class_ids.tolist(),
            np.asarray(det.scores, dtype=np.float64).tolist(),
            _rounded(det.boxes2d, (-1, 4), PIXEL_DECIMALS),
            amodal,
            _rounded(det.boxes3d, (-1, BOX_DIM), METRE_DECIMALS),
            _rounded(corners, (-1, 8, 3), METRE_DECIMALS),
            sources,
            strict=True,
        )
    ]
    line["timing"] = {k: float(v) for k, v in det.timing.items()}
    if det.gravity is not None:
        line["gravity"] = det.gravity
    if det.notes:
        line["notes"] = list(det.notes)
    return orjson.dumps(line).decode()


def _rounded(values: np.ndarray, shape: tuple[int, ...], decimals: int) -> list:
    # + 0.0 turns the -0.0 that rounding leaves into 0.0
    return (np.round(np.asarray(values, dtype=np.float64).reshape(shape), decimals) + 0.0).tolist()


def write_detections(path: str | os.PathLike, frames: Iterable[FrameDetections]) -> None:
    """Write a whole detections file atomically (``format_line`` per frame, for streaming writers)."""
    text = "".join(format_line(det) + "\n" for det in frames)
    atomic_write_bytes(path, text.encode("utf-8"))


def read_detections(path: str | os.PathLike) -> list[FrameDetections]:
    """All lines of a detections file, in file order, validated (InputError "FILE:LINE: ...")."""
    path = Path(path)
    frames: list[FrameDetections] = []
    seen: dict[str, int] = {}
    number = 0
    try:
        with open(path, encoding="utf-8") as f:  # streamed: NYUv2-size files are ~0.5 GB
            for number, raw in enumerate(f, start=1):
                if not raw.strip():
                    continue
                where = f"{path}:{number}"
                det = parse_line(raw, where)
                if det.frame in seen:
                    raise InputError(f"{where}: frame {det.frame!r} already given on line {seen[det.frame]}")
                seen[det.frame] = number
                frames.append(det)
    except FileNotFoundError:
        raise InputError(f"{path}: no such detections file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}:{number + 1}: not UTF-8 text") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read detections file ({e.strerror or e})") from None
    return frames


def parse_line(text: str, where: str) -> FrameDetections:
    """One validated line; ``where`` ("FILE:LINE") starts every error message."""
    obj = parse_json(text, where)
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    frame = obj.get("frame")
    if not isinstance(frame, str) or not frame:
        raise InputError(f"{where}: 'frame' must be a non-empty string")
    R_tilt = _array(obj.get("R_tilt"), (3, 3), where, "R_tilt")
    try:
        check_rotation(R_tilt, "R_tilt")
    except ValueError as e:
        raise InputError(f"{where}: {e}") from None
    pose = None
    if obj.get("pose") is not None:
        pose = check_pose(_array(obj["pose"], (4, 4), where, "pose"), f"{where}: pose")
    dets = obj.get("detections")
    if not isinstance(dets, list):
        raise InputError(f"{where}: 'detections' must be a list")
    for i, d in enumerate(dets):
        if not isinstance(d, dict):
            raise InputError(f"{where}: detection {i} is not an object")
        absent = [k for k in ("class", "score", "box2d", "box3d") if k not in d]
        if absent:
            raise InputError(f"{where}: detection {i} has no {', '.join(repr(k) for k in absent)}")
    class_ids = np.empty(len(dets), dtype=np.int64)
    for i, d in enumerate(dets):
        if not isinstance(d["class"], str) or d["class"] not in _CLASS_INDEX:
            raise InputError(f"{where}: detection {i}: unknown class {d['class']!r}")
        class_ids[i] = _CLASS_INDEX[d["class"]]
    scores = _array([d["score"] for d in dets], (len(dets),), where, "score")
    boxes2d = _array([d["box2d"] for d in dets], (len(dets), 4), where, "box2d")
    boxes3d = _array([d["box3d"] for d in dets], (len(dets), BOX_DIM), where, "box3d")
    for name, values in (("score", scores), ("box2d", boxes2d), ("box3d", boxes3d)):
        _require(np.isfinite(values), where, f"'{name}' is not finite")
    _require(boxes2d[:, 2:] >= boxes2d[:, :2], where, "box2d has x2 < x1 or y2 < y1")
    _require(boxes3d[:, SIZE] > 0, where, "box3d has a size l, w or h <= 0")
    corners = _optional_rows(dets, "corners", (8, 3), where)
    boxes2d_amodal = _optional_rows(dets, "box2d_amodal", (4,), where)
    if boxes2d_amodal is not None:
        _require(boxes2d_amodal[:, 2:] >= boxes2d_amodal[:, :2], where, "box2d_amodal has x2 < x1 or y2 < y1")
    return FrameDetections(
        frame=frame,
        R_tilt=R_tilt,
        class_ids=class_ids,
        scores=scores,
        boxes2d=boxes2d,
        boxes3d=boxes3d,
        corners=corners,
        color=_optional_str(obj, "color", where),
        depth=_optional_str(obj, "depth", where),
        timing=_timing(obj.get("timing", {}), where),
        boxes2d_amodal=boxes2d_amodal,
        gravity=_optional_str(obj, "gravity", where),
        notes=_notes(obj.get("notes", []), where),
        pose=pose,
        sources=_sources(dets, where),
    )


def _sources(dets: list[dict], where: str) -> tuple[str, ...] | None:
    """The optional per-detection ``source``: a non-empty string for every detection or for none."""
    given = sum("source" in d for d in dets)
    if given == 0:
        return None
    if given < len(dets):
        raise InputError(f"{where}: 'source' given for some detections but not all")
    bad = [i for i, d in enumerate(dets) if not (isinstance(d["source"], str) and d["source"])]
    if bad:
        raise InputError(f"{where}: detection {bad[0]}: 'source' must be a non-empty string")
    return tuple(d["source"] for d in dets)


def _notes(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(note, str) for note in value):
        raise InputError(f"{where}: 'notes' must be a list of strings")
    return tuple(value)


def _array(value, shape: tuple[int, ...], where: str, what: str) -> np.ndarray:
    """A float64 array of exactly ``shape``; for per-detection fields ``shape[0]`` is N, rows finite."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float64
        arr = None
    if arr is not None and arr.size == 0 and shape[0] == 0:
        arr = arr.reshape(shape)
    if arr is None or arr.shape != shape:
        got = "ragged or non-numeric values" if arr is None else f"shape {arr.shape}"
        if what in ("R_tilt", "pose"):
            raise InputError(f"{where}: '{what}' must be a {shape[0]}x{shape[1]} matrix, got {got}")
        expect = "x".join(map(str, shape[1:])) or "a number"
        raise InputError(f"{where}: every detection's '{what}' must be {expect}, got {got}")
    return arr


def _optional_rows(dets: list[dict], key: str, shape: tuple[int, ...], where: str) -> np.ndarray | None:
    """An optional per-detection field: given for every detection (finite, of ``shape``) or for none."""
    given = sum(key in d for d in dets)
    if given == 0:
        return None
    if given < len(dets):
        raise InputError(f"{where}: '{key}' given for some detections but not all")
    rows = _array([d[key] for d in dets], (len(dets), *shape), where, key)
    _require(np.isfinite(rows), where, f"'{key}' is not finite")
    return rows


def _require(ok: np.ndarray, where: str, problem: str) -> None:
    """Raise naming the first detection (row) where ``ok`` fails."""
    ok = ok.all(axis=tuple(range(1, ok.ndim)))
    bad = np.flatnonzero(~ok)
    if len(bad):
        raise InputError(f"{where}: detection {bad[0]}: {problem}")


def _optional_str(obj: dict, key: str, where: str) -> str | None:
    value = obj.get(key)
    if value is not None and not isinstance(value, str):
        raise InputError(f"{where}: '{key}' must be a string")
    return value


def _timing(value, where: str) -> dict[str, float]:
    ok = isinstance(value, dict) and all(is_finite_number(v) for v in value.values())
    if not ok:
        raise InputError(f"{where}: 'timing' must map stage names to seconds (finite numbers)")
    return {str(k): float(v) for k, v in value.items()}
