"""What a model finds in real frames that have no 3D ground truth, against hand-drawn 2D boxes.

    .venv/bin/python -m bench.real_frames FOLDER --model runtime/models/live.onnx [--model-name LABEL] \\
        --boxes bench/data/real_frames_boxes.json [--threshold 0.5] --out DIR

mAP needs 3D boxes, and real frames such as the nine the project looked at have none; what a user
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

Writes DIR/contact_sheet.png (every frame a tile, bench.contact_sheet; each tile alone in
DIR/tiles/), DIR/real_frames.json (the numbers, with the missed objects and wrong detections per
frame) and DIR/detections.jsonl (the detections file, README "Detections format"), and prints the
table in markdown. A bad input (no such folder, a boxes file that names a frame the folder lacks,
an unknown class, a bad box) is one line on stderr and exit status 1.
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
from a3d.runtime.errors import InputError
from a3d.runtime.io.detections_io import FrameDetections, write_detections
from a3d.runtime.io.json_input import is_finite_number, parse_json
from a3d.runtime.sources.folder import FolderSource
from a3d.runtime.structures.classes import CLASSES, class_index
from a3d.runtime.structures.geometry import iou_2d
from bench.contact_sheet import TileBoxes, contact_sheet, draw_tile

IOU = 0.5
DEFAULT_BOXES = Path(__file__).parent / "data" / "real_frames_boxes.json"
BOX_FIELDS = {"proposal": "boxes2d", "amodal": "boxes2d_amodal"}
_FILE_KEYS = ("about", "image_size", "frames")
_FRAME_KEYS = ("objects", "notes")
_OBJECT_KEYS = ("class", "box")


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
    """A frame's Count, and with it what a reader looks for next: the classes of the objects
    missed and the class and score of each wrong detection."""
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


def detect_all(source: FolderSource, model: Path, threads: int) -> list[tuple[FrameDetections, np.ndarray]]:
    """Each frame's detections and colour image (BGR), in folder order; a frame that fails stops
    the benchmark (its totals would be wrong)."""
    detector = Detector.load(model, threads=threads)
    results = []
    for outcome in detector.detect_frames(source, score_threshold=0):  # all: the count applies its own
        if outcome.detections is None or outcome.prepared is None:
            raise InputError(outcome.problem)
        results.append((outcome.detections, outcome.prepared.frame.color))
    return results


def run(args: argparse.Namespace) -> int:
    """The benchmark (module docstring); InputError on a bad input."""
    if not args.folder.is_dir():
        raise InputError(f"{args.folder}: no such frame folder")
    boxes = read_boxes(args.boxes)
    source = FolderSource(args.folder)
    check_frames(source, boxes)
    label = args.model_name or args.model.stem
    results = detect_all(source, args.model, args.threads)
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
    write_detections(args.out / "detections.jsonl", [det for det, _ in results])
    summary = {
        "model": str(args.model), "model_name": label, "boxes": str(args.boxes), "threshold": args.threshold,
        "iou": IOU, "box": args.box, "frames": reports, "total": total.as_dict(),
    }  # fmt: skip
    (args.out / "real_frames.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"{label} on {args.folder} ({len(results)} frames), detections >= {args.threshold:g}, "
          f"{args.box} box IoU >= {IOU} with a hand-drawn object of the same class:\n")  # fmt: skip
    print(markdown_table(counts, total))
    print(f"\nwrote {args.out / 'contact_sheet.png'}, {args.out / 'real_frames.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="an a3d frame folder of real frames")
    parser.add_argument("--model", type=Path, required=True, help="the ONNX model to run")
    parser.add_argument(
        "--model-name", help="the model's name on the sheet and in the JSON (default: its stem)"
    )
    parser.add_argument("--boxes", type=Path, default=DEFAULT_BOXES, help="the hand-drawn boxes file")
    parser.add_argument("--threshold", type=float, default=0.5, help="lowest score counted and drawn")
    parser.add_argument("--box", choices=sorted(BOX_FIELDS), default="proposal", help="the 2D box compared")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True, help="folder for the sheet and the JSON")
    args = parser.parse_args(argv)
    try:
        return run(args)
    except (InputError, ValueError, OSError) as e:
        print(f"real_frames: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
