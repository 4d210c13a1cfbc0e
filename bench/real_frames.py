"""What a model finds in real frames that have no 3D ground truth, against hand-drawn 2D boxes.

    .venv/bin/python -m bench.real_frames FOLDER --model live|real|FILE [--detector NAME|FILE|none] \\
        [--classifier NAME|FILE] \\
        [--model-name LABEL] --boxes bench/data/real_frames_boxes.json \\
        [--boxes3d bench/data/real_frames_boxes3d.json | --no-3d] [--threshold 0.5] --out DIR
    .venv/bin/python -m bench.real_frames FOLDER --detector yolox-nano --detector-alone --out DIR
    .venv/bin/python -m bench.real_frames FOLDER --classifier mobilenet-v2 --classifier-alone --out DIR

``--model real`` is the bundled pipeline (the network with its 2D detector, a3d.runtime.models);
``--detector-alone`` counts a 2D detector's own boxes and scores, its classes mapped to a3d's, in 2D.
``--classifier-alone`` runs an image classifier on the hand-drawn boxes themselves: per class, the
probability it gives the object's own class, the most it could vouch for in a pipeline.

mAP needs 3D boxes, and real frames such as the nine the project looked at come without any; what a user
sees is which boxes a model draws on them. This runs the model on every frame of FOLDER (an a3d
frame folder) through the runtime's Python API, and counts its detections at or above the
threshold against the boxes file (bench/data/real_frames_boxes.json: every plainly visible object
of the 19 classes drawn by hand as its visible 2D extent). A detection is right when its class is
the object's and its 2D box overlaps the object's with IoU >= 0.5; detections are matched greedily
by descending score, one per object, so a duplicate counts as a wrong detection. Per frame and in
total: objects, found (objects matched), detections >= threshold, right (detections matched: equal
to found under one-to-one matching, a column of its own as the numerator of precision), recall
(found / objects) and precision (right / detections).

The 2D box compared is ``box2d``, the proposal box: proposals are boxes of visible segments, as the
hand-drawn boxes are visible extents, while ``box2d_amodal`` is the network's regression towards
the amodal box (through occluders and off the image edge). ``--box amodal`` counts with that one.

In 3D (bench.real_frames_3d), against the amodal 3D boxes that bench/data/real_frames_boxes3d.json
gives most of the hand-drawn objects (fitted once and corrected by hand, bench.real_frames_fit):
AP@0.25 per class and their mean over the classes with a 3D box, a3d's own metric over all
detections, and the median 3D IoU of the objects found above. ``--no-3d`` counts in 2D only, for
a folder whose objects have no 3D boxes.

Writes DIR/contact_sheet.png (every frame a tile, bench.contact_sheet; each tile alone in
DIR/tiles/), DIR/real_frames.json (the numbers, with the objects found and missed and the wrong
detections per frame, and the 3D numbers under "3d") and DIR/detections.jsonl (the detections
file, README "Detections format"), and prints the tables in markdown. A bad input (no such folder,
a boxes file that names a frame the folder lacks, an unknown class, a bad box, a 3D boxes file
that does not match the boxes file) is one line on stderr and exit status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from a3d.runtime import Detector
from a3d.runtime.detector2d import Detector2D
from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.metric import FrameTruth
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.io.json_input import is_finite_number, parse_json
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.classes import CLASSES, class_index
from a3d.runtime.structures.geometry import check_rotation, iou_2d
from bench.contact_sheet import TileBoxes, contact_sheet, draw_tile
from bench.real_frames_3d import IOU_3D, Score3D, as_dict, markdown_3d, score_3d

IOU = 0.5
DEFAULT_BOXES = Path(__file__).parent / "data" / "real_frames_boxes.json"
BOX_FIELDS = {"proposal": "boxes2d", "amodal": "boxes2d_amodal"}
_FILE_KEYS = ("about", "image_size", "frames")
_FRAME_KEYS = ("objects", "notes")
_OBJECT_KEYS = ("class", "box")
DEFAULT_BOXES3D = Path(__file__).parent / "data" / "real_frames_boxes3d.json"
_FILE3D_KEYS = ("about", "frames")
_FRAME3D_KEYS = ("R_tilt", "objects", "skipped")
_OBJECT3D_KEYS = ("object", "class", "box3d", "note")
_SKIPPED_KEYS = ("object", "class", "why")


# ----------------------------------------------------------------------------- the boxes file


@dataclass(frozen=True)
class HandBoxes:
    """One frame's hand-drawn objects: 0-based CLASSES indices and [x1, y1, x2, y2] boxes."""

    class_ids: np.ndarray  # (N,) int64
    boxes: np.ndarray  # (N, 4) float64
    notes: str = ""


@dataclass(frozen=True)
class BoxesFile:
    """A validated boxes file: the image size its boxes are drawn on and each frame's objects."""

    path: Path
    image_size: tuple[int, int]  # (width, height)
    frames: dict[str, HandBoxes]


def read_boxes(path: Path) -> BoxesFile:
    """Read and validate a boxes file; every problem is ``InputError("PATH: where: what")``, so a
    typo in a hand-edited file stops the benchmark instead of silently costing recall."""
    try:
        text = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read the boxes file ({e.strerror or e})") from None
    doc = _mapping(parse_json(text, str(path), "boxes file"), path, "the file", _FILE_KEYS)
    size = doc.get("image_size", [640, 480])
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise InputError(f"{path}: image_size must be [width, height] in pixels, got {_preview(size)}")
    frames = doc.get("frames")
    if not isinstance(frames, dict) or not frames:
        raise InputError(f"{path}: 'frames' must be an object of frame name -> {{objects, notes}}")
    width, height = size
    parsed = {name: _frame(entry, path, f"frames.{name}", (width, height)) for name, entry in frames.items()}
    return BoxesFile(path, (width, height), parsed)


def _frame(entry: Any, path: Path, where: str, size: tuple[int, int]) -> HandBoxes:
    """One frame's entry (an empty object list is allowed: a frame with nothing to find)."""
    entry = _mapping(entry, path, where, _FRAME_KEYS)
    objects = entry.get("objects")
    if not isinstance(objects, list):
        raise InputError(f"{path}: {where}.objects must be a list")
    notes = entry.get("notes", "")
    if not isinstance(notes, str):
        raise InputError(f"{path}: {where}.notes must be a string")
    ids, boxes = [], []
    for i, obj in enumerate(objects):
        what = f"{where}.objects[{i}]"
        obj = _mapping(obj, path, what, _OBJECT_KEYS)
        if not isinstance(obj.get("class"), str):
            raise InputError(f"{path}: {what}: 'class' must be a class name")
        try:
            ids.append(class_index(obj["class"]))
        except ValueError as e:
            raise InputError(f"{path}: {what}: {e}") from None
        boxes.append(_box(obj.get("box"), path, what, size))
    return HandBoxes(np.asarray(ids, np.int64), np.asarray(boxes, np.float64).reshape(-1, 4), notes)


def _box(value: Any, path: Path, what: str, size: tuple[int, int]) -> list[float]:
    """[x1, y1, x2, y2] with x1 < x2, y1 < y2, inside the image (0..width, 0..height)."""
    if not (isinstance(value, list) and len(value) == 4 and all(is_finite_number(v) for v in value)):
        raise InputError(f"{path}: {what}: 'box' must be [x1, y1, x2, y2] (4 numbers), got {_preview(value)}")
    x1, y1, x2, y2 = (float(v) for v in value)
    if not (x1 < x2 and y1 < y2):
        raise InputError(f"{path}: {what}: box {value} is empty or reversed (needs x1 < x2 and y1 < y2)")
    if not (0 <= x1 and 0 <= y1 and x2 <= size[0] and y2 <= size[1]):
        raise InputError(f"{path}: {what}: box {value} is outside the {size[0]}x{size[1]} image")
    return [x1, y1, x2, y2]


# ----------------------------------------------------------------------------- the 3D boxes file


@dataclass(frozen=True)
class Boxes3D:
    """One frame's 3D boxes (``truth``: classes, camera-frame boxes, the R_tilt their yaw is in)
    and which of its hand-drawn objects (0-based, the boxes file's order) each one is."""

    truth: FrameTruth
    objects: np.ndarray  # (N,) int64


def read_boxes3d(path: Path, boxes: BoxesFile) -> dict[str, Boxes3D]:
    """Read and validate a 3D boxes file against the boxes file it completes: the same frames, and
    every hand-drawn object either boxed (same class) or skipped with a reason, exactly once.
    Problems are ``InputError("PATH: where: what")``, as for ``read_boxes``."""
    try:
        text = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read the 3D boxes file ({e.strerror or e})") from None
    doc = _mapping(parse_json(text, str(path), "3D boxes file"), path, "the file", _FILE3D_KEYS)
    frames = doc.get("frames")
    if not isinstance(frames, dict) or set(frames) != set(boxes.frames):
        names = ", ".join(boxes.frames)
        raise InputError(f"{path}: 'frames' must name the frames of {boxes.path} ({names}), no other")
    return {name: _frame3d(frames[name], path, f"frames.{name}", hand) for name, hand in boxes.frames.items()}


def _frame3d(entry: Any, path: Path, where: str, hand: HandBoxes) -> Boxes3D:
    """One frame's entry: its R_tilt, boxed objects and skipped ones."""
    entry = _mapping(entry, path, where, _FRAME3D_KEYS)
    try:
        R_tilt = check_rotation(np.asarray(entry.get("R_tilt"), np.float64), f"{where}.R_tilt")
    except InputError as e:
        raise InputError(f"{path}: {e}") from None
    except (ValueError, TypeError):  # ragged rows or no numbers
        raise InputError(f"{path}: {where}.R_tilt must be a 3x3 rotation (rows of numbers)") from None
    listed, boxed = [], []
    for key, fields in (("objects", _OBJECT3D_KEYS), ("skipped", _SKIPPED_KEYS)):
        items = entry.get(key, [])
        if not isinstance(items, list):
            raise InputError(f"{path}: {where}.{key} must be a list")
        for i, item in enumerate(items):
            what = f"{where}.{key}[{i}]"
            item = _mapping(item, path, what, fields)
            listed.append(_hand_object(item, path, what, hand))
            if key == "objects":
                boxed.append(_box3d(item.get("box3d"), path, what))
            elif not (isinstance(item.get("why"), str) and item["why"]):
                raise InputError(f"{path}: {what}: 'why' must say why the object has no 3D box")
    for index in range(len(hand.class_ids)):
        if listed.count(index) != 1:
            how = "listed twice" if listed.count(index) else "neither boxed nor skipped"
            raise InputError(f"{path}: {where}: hand-drawn object {index} is {how}")
    objects = np.asarray(listed[: len(boxed)], np.int64)
    boxes3d = np.asarray(boxed, np.float64).reshape(-1, 7)
    return Boxes3D(FrameTruth(hand.class_ids[objects], boxes3d, R_tilt), objects)


def _hand_object(item: dict, path: Path, what: str, hand: HandBoxes) -> int:
    """The index of the hand-drawn object an entry names, checked against that object's class."""
    index = item.get("object")
    if isinstance(index, bool) or not (isinstance(index, int) and 0 <= index < len(hand.class_ids)):
        raise InputError(
            f"{path}: {what}: 'object' must index the frame's {len(hand.class_ids)} hand-drawn objects, "
            f"got {_preview(index)}"
        )
    expected = CLASSES[hand.class_ids[index]]
    if item.get("class") != expected:
        raise InputError(
            f"{path}: {what}: 'class' must be {expected!r} (hand-drawn object {index}), "
            f"got {_preview(item.get('class'))}"
        )
    return index


def _box3d(value: Any, path: Path, what: str) -> list[float]:
    """[x, y, z, l, w, h, theta] in canonical form: l >= w > 0, h > 0, theta in [-pi/2, pi/2]."""
    if not (isinstance(value, list) and len(value) == 7 and all(is_finite_number(v) for v in value)):
        raise InputError(
            f"{path}: {what}: 'box3d' must be [x, y, z, l, w, h, theta] (7 numbers), got {_preview(value)}"
        )
    x, y, z, l, w, h, theta = (float(v) for v in value)
    if not (l >= w > 0 and h > 0 and abs(theta) <= np.pi / 2):
        raise InputError(f"{path}: {what}: box3d {value} needs l >= w > 0, h > 0 and |theta| <= pi/2")
    return [x, y, z, l, w, h, theta]


def _mapping(value: Any, path: Path, where: str, known: tuple[str, ...]) -> dict:
    """``value`` as a JSON object with no keys outside ``known`` (a misspelt key is a lost box)."""
    if not isinstance(value, dict):
        raise InputError(f"{path}: {where} must be a JSON object")
    unknown = sorted(set(value) - set(known))
    if unknown:
        raise InputError(f"{path}: {where}: unknown key {unknown[0]!r} (expected {', '.join(known)})")
    return value


def _preview(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


# ----------------------------------------------------------------------------- counting


@dataclass(frozen=True)
class Count:
    """One frame's (or all frames') numbers; see the module docstring."""

    objects: int
    found: int
    detections: int
    right: int

    @property
    def recall(self) -> float | None:
        return self.found / self.objects if self.objects else None

    @property
    def precision(self) -> float | None:
        return self.right / self.detections if self.detections else None

    def __add__(self, other: Count) -> Count:
        return Count(*(a + b for a, b in zip(asdict(self).values(), asdict(other).values(), strict=True)))

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "recall": self.recall, "precision": self.precision}


@dataclass(frozen=True)
class FrameMatch:
    """A frame's detections as compared: classes, scores and the chosen 2D box of each."""

    class_ids: np.ndarray
    scores: np.ndarray
    boxes: np.ndarray


def match(
    truth: HandBoxes,
    class_ids: np.ndarray,
    scores: np.ndarray,
    boxes: np.ndarray,
    threshold: float,
    iou: float = IOU,
) -> np.ndarray:
    """For each detection the index of the object it is matched to, -1 for none (below the
    threshold, another class, IoU < ``iou``, or its object already taken by a higher score).

    Greedy by descending score, each detection taking the free object of its class it overlaps
    most: the usual detection-benchmark rule, so a duplicate box cannot count twice."""
    matched = np.full(len(scores), -1, np.int64)
    if len(scores) == 0 or len(truth.class_ids) == 0:
        return matched
    overlaps = iou_2d(np.asarray(boxes, np.float64), truth.boxes)
    free = np.ones(len(truth.class_ids), bool)
    for d in np.argsort(-np.asarray(scores), kind="stable"):
        if scores[d] < threshold:
            break
        candidates = np.where(free & (truth.class_ids == class_ids[d]), overlaps[d], -1.0)
        best = int(np.argmax(candidates))
        if candidates[best] >= iou:
            matched[d], free[best] = best, False
    return matched


def count(
    truth: HandBoxes, class_ids: np.ndarray, scores: np.ndarray, boxes: np.ndarray, threshold: float
) -> Count:
    """The frame's Count (``match``)."""
    return frame_report(truth, FrameMatch(class_ids, scores, boxes), threshold)[0]


def frame_report(truth: HandBoxes, dets: FrameMatch, threshold: float) -> tuple[Count, dict[str, Any]]:
    """A frame's Count, and with it what a reader looks for next: the objects found (indices), the
    classes of the objects missed and the class and score of each wrong detection."""
    matched = match(truth, dets.class_ids, dets.scores, dets.boxes, threshold)
    kept = np.asarray(dets.scores) >= threshold
    right = int((matched >= 0).sum())
    counted = Count(len(truth.class_ids), right, int(kept.sum()), right)
    taken = set(matched[matched >= 0].tolist())
    wrong = [
        {"class": CLASSES[c], "score": round(float(s), 3)}
        for c, s, m, k in zip(dets.class_ids, dets.scores, matched, kept, strict=True)
        if k and m < 0
    ]
    details = {
        "found_objects": sorted(taken),
        "missed": [CLASSES[c] for i, c in enumerate(truth.class_ids) if i not in taken],
        "wrong": sorted(wrong, key=lambda w: -w["score"]),
    }
    return counted, details


def markdown_table(rows: dict[str, Count], total: Count) -> str:
    """The per-frame table and its total, in markdown."""

    def share(value: float | None) -> str:
        return "-" if value is None else f"{100 * value:.0f}%"

    lines = [
        "| frame | objects | found | detections | right | recall | precision |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, c in [*rows.items(), ("**total**", total)]:
        numbers = (c.objects, c.found, c.detections, c.right, share(c.recall), share(c.precision))
        lines.append("| " + " | ".join(str(v) for v in (name, *numbers)) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the run


def check_frames(source: FolderSource, boxes: BoxesFile) -> None:
    """The folder's frames and the boxes file name the same frames (a frame left out of either
    would change the totals without a word)."""
    names = {ref.name for ref in source.refs}
    absent = [name for name in boxes.frames if name not in names]
    if absent:
        raise InputError(f"{boxes.path}: frame {absent[0]!r} is not a frame of {source.folder}")
    unboxed = sorted(names - set(boxes.frames))
    if unboxed:
        raise InputError(f"{boxes.path}: no entry for frame {unboxed[0]!r} of {source.folder}")


def detect_all(
    source: FolderSource, model: Path, threads: int, detector: str | None = None,
    classifier: str | None = None,
) -> list[tuple[FrameDetections, np.ndarray]]:  # fmt: skip
    """Each frame's detections and colour image (BGR), in folder order; a frame that fails stops
    the benchmark (its totals would be wrong). ``detector``, ``classifier``: Detector.load's (None:
    the model's detector, no classifier)."""
    detector = Detector.load(model, threads=threads, detector=detector, classifier=classifier)
    results = []
    for outcome in detector.detect_frames(source, score_threshold=0):  # all: the count applies its own
        if outcome.detections is None or outcome.prepared is None:
            raise InputError(outcome.problem)
        results.append((outcome.detections, outcome.prepared.frame.color))
    return results


def detector_alone(source: FolderSource, name: str, threads: int) -> list[tuple[FrameDetections, np.ndarray]]:
    """The 2D detector's own boxes and scores of each frame, its classes mapped to a3d's (the first
    candidate), without the network: 2D only (the boxes3d are placeholders, never counted)."""
    detector = Detector2D.load(name, threads=threads)
    results = []
    for loader in source:
        frame = loader.load()
        found = detector.detect(np.ascontiguousarray(frame.color[..., ::-1]))
        det = FrameDetections(frame.name, np.eye(3), found.class_ids, found.scores, found.boxes,
                              np.zeros((len(found.scores), 7)), color=frame.color_file)  # fmt: skip
        results.append((det, frame.color))
    return results


def classifier_alone(source: FolderSource, boxes: BoxesFile, name: str, threads: int) -> str:
    """Per class of the hand-drawn objects, in markdown: how many, the median probability the
    classifier gives their own class on their own boxes, and how many it names so at >= 0.5."""
    from a3d.runtime.classifier2d import Classifier2D

    classifier = Classifier2D.load(name, threads=threads)
    probs: dict[int, list[float]] = {}
    for loader in source:
        frame = loader.load()
        truth = boxes.frames[frame.name]
        p = classifier.classify(np.ascontiguousarray(frame.color[..., ::-1]), truth.boxes)
        for c, row in zip(truth.class_ids, p, strict=True):
            probs.setdefault(int(c), []).append(float(row[c]))
    lines = ["| class | objects | median p(own class) | named at >= 0.5 |", "|---|---:|---:|---:|"]
    for c in sorted(probs, key=lambda c: CLASSES[c]):
        own = np.array(probs[c])
        lines.append(f"| {CLASSES[c]} | {len(own)} | {np.median(own):.2f} | {(own >= 0.5).sum()} |")
    return "\n".join(lines)


def _in_3d(
    boxes3d: dict[str, Boxes3D], detections: list[FrameDetections], reports: dict[str, dict], threshold: float
) -> Score3D:
    """The 3D score of the run's detections (bench.real_frames_3d): an object is found when the 2D
    count found it."""
    found = {name: np.isin(b.objects, reports[name]["found_objects"]) for name, b in boxes3d.items()}
    truth = {name: b.truth for name, b in boxes3d.items()}
    return score_3d(truth, {det.frame: det for det in detections}, found, threshold)


def run(args: argparse.Namespace) -> int:
    """The benchmark (module docstring); InputError on a bad input."""
    if not args.folder.is_dir():
        raise InputError(f"{args.folder}: no such frame folder")
    boxes = read_boxes(args.boxes)
    source = FolderSource(args.folder)
    check_frames(source, boxes)
    if args.classifier_alone:  # the hand-drawn boxes alone: no 3D boxes file is read
        print(f"{args.classifier} on the hand-drawn boxes of {args.folder} (crops as in the pipeline):\n")
        print(classifier_alone(source, boxes, args.classifier, args.threads))
        return 0
    alone = args.detector_alone
    boxes3d = None if args.no_3d or alone else read_boxes3d(args.boxes3d, boxes)
    if alone:
        label = args.model_name or f"{args.detector} alone"
        results = detector_alone(source, args.detector, args.threads)
    else:
        label = args.model_name or args.model.stem
        results = detect_all(source, args.model, args.threads, args.detector, args.classifier)
    counts, reports, tiles = {}, {}, []
    for det, color in results:
        truth = boxes.frames[det.frame]
        if color.shape[1::-1] != boxes.image_size:
            raise InputError(
                f"{det.color}: the image is {color.shape[1]}x{color.shape[0]}, the boxes in {boxes.path} "
                f"are for {boxes.image_size[0]}x{boxes.image_size[1]}"
            )
        compared = getattr(det, BOX_FIELDS[args.box])
        if compared is None:
            raise InputError(f"{args.model}: the model gives no amodal 2D boxes (use --box proposal)")
        c, details = frame_report(truth, FrameMatch(det.class_ids, det.scores, compared), args.threshold)
        counts[det.frame], reports[det.frame] = c, {**c.as_dict(), **details}
        keep = det.scores >= args.threshold
        title = f"{det.frame}: found {c.found}/{c.objects}, right {c.right}/{c.detections}"
        shown = TileBoxes(det.class_ids[keep], det.scores[keep], compared[keep], truth.boxes)
        tiles.append(draw_tile(color, title, shown))
    total = sum(counts.values(), Count(0, 0, 0, 0))
    (args.out / "tiles").mkdir(parents=True, exist_ok=True)
    for det_and_color, tile in zip(results, tiles, strict=True):  # one picture per frame, for the docs
        cv2.imwrite(str(args.out / "tiles" / f"{det_and_color[0].frame}.png"), tile)
    header = (
        f"{label}: {args.box} boxes of detections >= {args.threshold:g} (viewer class colours); "
        f"dashed grey: hand-drawn objects"
    )
    cv2.imwrite(str(args.out / "contact_sheet.png"), contact_sheet(tiles, columns=3, header=header))
    if not alone:
        write_detections(args.out / "detections.jsonl", [det for det, _ in results])
    summary = {
        "model": str(args.model), "model_name": label, "boxes": str(args.boxes), "threshold": args.threshold,
        "iou": IOU, "box": args.box, "frames": reports, "total": total.as_dict(),
    }  # fmt: skip
    if boxes3d is not None:
        score = _in_3d(boxes3d, [det for det, _ in results], reports, args.threshold)
        objects = {name: b.objects for name, b in boxes3d.items()}
        summary["3d"] = {"boxes3d": str(args.boxes3d), **as_dict(score, objects)}
    (args.out / "real_frames.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"{label} on {args.folder} ({len(results)} frames), detections >= {args.threshold:g}, "
          f"{args.box} box IoU >= {IOU} with a hand-drawn object of the same class:\n")  # fmt: skip
    print(markdown_table(counts, total))
    if boxes3d is not None:
        print(f"\nIn 3D, against {args.boxes3d}: all detections, 3D IoU >= {IOU_3D} (a3d-eval, the paper's "
              f"protocol), over the classes with a 3D box:\n")  # fmt: skip
        print(markdown_3d(score))
    print(f"\nwrote {args.out / 'contact_sheet.png'}, {args.out / 'real_frames.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="an a3d frame folder of real frames")
    parser.add_argument("--model", type=Path, help="the model to run: a bundled name (live, real) or file")
    parser.add_argument("--detector", help="a 2D detector whose boxes join the model's RoIs ('none': none; "
                        "default: the model's pipeline's)")  # fmt: skip
    parser.add_argument("--classifier", help="an image classifier that rescores the model's own detections "
                        "(a3d.runtime.classifier2d; default: none)")  # fmt: skip
    parser.add_argument("--detector-alone", action="store_true",
                        help="count --detector's own boxes and scores, no network (2D only)")  # fmt: skip
    parser.add_argument("--classifier-alone", action="store_true",
                        help="run --classifier on the hand-drawn boxes (a table, no model)")  # fmt: skip
    parser.add_argument(
        "--model-name", help="the model's name on the sheet and in the JSON (default: its stem)"
    )
    parser.add_argument("--boxes", type=Path, default=DEFAULT_BOXES, help="the hand-drawn boxes file")
    parser.add_argument(
        "--boxes3d", type=Path, default=DEFAULT_BOXES3D, help="the 3D boxes of the boxes file's objects"
    )
    parser.add_argument("--no-3d", action="store_true", help="count in 2D only (a folder without 3D boxes)")
    parser.add_argument("--threshold", type=float, default=0.5, help="lowest score counted and drawn")
    parser.add_argument("--box", choices=sorted(BOX_FIELDS), default="proposal", help="the 2D box compared")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True, help="folder for the sheet and the JSON")
    args = parser.parse_args(argv)
    if args.classifier_alone:
        if not args.classifier or args.model or args.detector_alone:
            parser.error("--classifier-alone takes --classifier NAME and no --model or --detector-alone")
    elif (args.model is None) != args.detector_alone or (args.detector_alone and not args.detector):
        parser.error("give --model, or --detector NAME with --detector-alone")
    try:
        return run(args)
    except (InputError, ValueError, OSError) as e:
        print(f"real_frames: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
