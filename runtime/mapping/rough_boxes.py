"""The rough boxes a person types for a recording (a3d-world-boxes): a small CSV, one object a row.

    # comment lines start with '#'
    class,x,y,z,l,w,h,yaw_deg
    sofa,2.1,-0.4,3.6,2.0,0.9,0.8,90

Why a CSV and degrees: the person reads centres and extents off the rerun view of the fused cloud
and types them in a text editor; a hand's width off is fine (a3d.runtime.mapping.box_fit fits
them). The world is the recording's (y down, metres); yaw is about y, in degrees, as a person
turns a box. Reading is strict: every problem is one ``InputError`` naming the file and the line.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.image_io import read_bytes
from a3d.runtime.structures.classes import CLASSES

COLUMNS = ("class", "x", "y", "z", "l", "w", "h", "yaw_deg")


@dataclass(frozen=True)
class RoughBoxes:
    """N rough boxes: class names, world 7-vectors (N, 7) (yaw in radians) and their file lines."""

    classes: list[str]
    boxes: np.ndarray
    lines: list[int]


def row_text(name: str, box: np.ndarray) -> str:
    """One CSV row of a box (world 7-vector, yaw in radians): centimetres, and tenths of a degree."""
    return ",".join([name, *(f"{v:.3f}" for v in box[:6]), f"{math.degrees(box[6]):.1f}"])


def template(notes: list[str], rows: list[tuple[str, str, np.ndarray]] = ()) -> str:
    """The file a first run writes for the person to fill in: ``notes`` as comments, the header,
    then ``rows`` (a comment, a class, a world box) proposed for the person to correct."""
    head = [
        "a3d-world-boxes rough boxes: one object a row, read off the rerun view of the fused cloud.",
        "World metres, y down (the floor has the largest y); yaw in degrees about y;",
        "a hand's width off is fine: each box is fitted to the points inside it.",
        f"Classes: {', '.join(CLASSES)}.",
        "Example row: sofa,2.1,-0.4,3.6,2.0,0.9,0.8,90",
        *notes,
    ]
    proposed = "".join(f"# {comment}\n{row_text(name, box)}\n" for comment, name, box in rows)
    return "".join(f"# {line}\n" for line in head) + ",".join(COLUMNS) + "\n" + proposed


def write_template(
    path: str | os.PathLike, notes: list[str], rows: list[tuple[str, str, np.ndarray]] = ()
) -> None:
    atomic_write_bytes(path, template(notes, rows).encode("utf-8"))


def read_rough_boxes(path: str | os.PathLike) -> RoughBoxes:
    """The file's boxes, validated ("PATH:LINE: problem" on the first problem; no rows is one too)."""
    path = Path(path)
    text = read_bytes(path).decode("utf-8", errors="replace")
    lines_read = enumerate(text.splitlines(), 1)
    rows = [(n, line) for n, line in lines_read if line.strip() and not line.lstrip().startswith("#")]
    header = ",".join(COLUMNS)
    if not rows or tuple(c.strip() for c in rows[0][1].split(",")) != COLUMNS:
        raise InputError(f"{path}: the first row that is not a comment must be the header {header}")
    classes, boxes, lines = [], [], []
    for n, line in rows[1:]:
        where = f"{path}:{n}"
        values = [v.strip() for v in next(csv.reader([line]))]
        if len(values) != len(COLUMNS):
            raise InputError(f"{where}: {len(values)} values, expected {len(COLUMNS)} ({header})")
        if values[0] not in CLASSES:
            raise InputError(f"{where}: class {values[0]!r} is not one of the 19 classes (see the comments)")
        try:
            numbers = [float(v) for v in values[1:]]
        except ValueError:
            raise InputError(f"{where}: x, y, z, l, w, h and yaw_deg must be numbers, got {line!r}") from None
        if not all(math.isfinite(v) for v in numbers) or min(numbers[3:6]) <= 0:
            raise InputError(f"{where}: numbers must be finite and l, w, h positive, got {line!r}")
        classes.append(values[0])
        boxes.append([*numbers[:6], math.radians(numbers[6])])
        lines.append(n)
    if not classes:
        raise InputError(f"{path}: no boxes yet; add one row per object under the header")
    return RoughBoxes(classes, np.array(boxes, np.float64), lines)
