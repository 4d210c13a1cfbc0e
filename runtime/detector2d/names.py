"""A 2D detector's class names: from a names file, the ONNX file's metadata, or COCO's 80.

Why: a detector's outputs are class indices; the class map (a3d.runtime.detector2d.class_map) is
keyed by names, so each index needs its name. YOLOX's and NanoDet's exports carry none, so an
80-class detector without names is taken to be COCO's (``COCO80``, YOLOX's own list).
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

from a3d.runtime.errors import InputError

# COCO 2017's 80 detection classes in training order, spelt as YOLOX's coco_classes.py spells them
# (Darknet's coco.names has the same order with other spellings: sofa, diningtable, tvmonitor, ...).
COCO80: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant",
    "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
)  # fmt: skip
METADATA_KEY = "names"


def read_names_file(path: Path) -> tuple[str, ...]:
    """One class name per line (blank lines skipped), as Darknet's coco.names."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"{path}: cannot read the class names file ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: the class names file is not UTF-8 text (byte {e.start})") from None
    names = tuple(line.strip() for line in text.splitlines() if line.strip())
    if not names:
        raise InputError(f"{path}: the class names file holds no name")
    return names


def names_from_metadata(value: str, where: str) -> tuple[str, ...]:
    """The ``names`` metadata entry: a JSON list of names, or a dict index -> name (JSON, or the
    Python literal ultralytics writes: ``{0: 'person', 1: 'bicycle'}``)."""
    try:
        parsed = json.loads(value)
    except (ValueError, RecursionError):
        try:
            parsed = ast.literal_eval(value)
        except (ValueError, SyntaxError, MemoryError, RecursionError):
            parsed = None
    if isinstance(parsed, dict):
        try:
            by_index = {int(k): v for k, v in parsed.items()}
        except (TypeError, ValueError):
            by_index = {}
        parsed = [by_index.get(i) for i in range(len(parsed))]
    if not (isinstance(parsed, list) and parsed and all(isinstance(n, str) and n for n in parsed)):
        raise InputError(
            f"{where}: metadata '{METADATA_KEY}' must be a list of class names or a dict index -> name "
            "(indices 0..N-1)"
        )
    return tuple(parsed)


def class_names(
    names_file: Path | None, metadata: dict[str, str], num_classes: int | None, where: str
) -> tuple[str, ...]:
    """The detector's names: the names file, else its metadata, else COCO80 for 80 classes.

    ``num_classes`` is the count the graph fixes (None: the graph does not say); a list of another
    length is an InputError naming its source and both counts."""
    if names_file is not None:
        names = read_names_file(names_file)
    elif METADATA_KEY in metadata:
        names = names_from_metadata(metadata[METADATA_KEY], where)
    elif num_classes == len(COCO80):
        return COCO80
    else:
        raise InputError(
            f"{where}: no class names (no '{METADATA_KEY}' metadata and not an 80-class COCO detector); "
            "give a names file"
        )
    if num_classes is not None and len(names) != num_classes:
        source, graph = (
            (f"{names_file}: the names file", f"the detector {where}")
            if names_file is not None
            else (f"{where}: the metadata", "the graph")
        )
        raise InputError(f"{source} has {len(names)} class names but {graph} has {num_classes} classes")
    return names
