"""Draft 3D boxes for the hand-drawn objects of the real frames, and the pictures to check them by.

    .venv/bin/python -m bench.real_frames_fit REAL_FRAMES --fit DRAFT.json   # the draft, once
    .venv/bin/python -m bench.real_frames_fit REAL_FRAMES --draw DIR        # re-check the committed file
    .venv/bin/python -m bench.real_frames_fit REAL_FRAMES --draw DIR --detections RUN/detections.jsonl

The real frames have no 3D ground truth; bench/data/real_frames_boxes3d.json gives their
hand-drawn objects (bench/data/real_frames_boxes.json) amodal 3D boxes for bench.real_frames's 3D
score, fitted once and corrected by hand: the file is the truth, this is how it was made and how
to look at it. ``--fit`` writes the draft the correction started from: per frame the R_tilt a3d
estimates (the pipeline's ``choose_gravity`` on the raw and hole-filled depth) and the floor plane;
per object the depth pixels inside its 2D box, in the tilt frame, without the floor, split into
clusters by distance from the camera, of which the largest is taken for the object; a rough box
round that cluster's bulk goes to ``a3d.runtime.mapping.box_fit.fit_box``, and a class that stands
on the floor is extended down to it. An object with too few points is listed as skipped. The
hand correction (which points are the object's, the amodal extent of hidden parts) is in the
file's notes.

``--draw`` writes the pictures of bench.real_frames_views for every frame and boxed object, and a
contact sheet of all frames (the one in docs/images/real_frames_boxes3d.jpg). With
``--detections`` (bench.real_frames's DIR/detections.jsonl, or a3d-run's) the frames' pictures
and the sheet (DIR/detections_boxes3d.jpg, the one in docs/images/real_frames_real_3d.jpg) also
hold the 3D boxes of the detections scoring ``--threshold`` or more, beside the truth's in grey.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.depth import fill_depth_info
from a3d.runtime.frontend.gravity import choose_gravity
from a3d.runtime.io.detections_io import FrameDetections, read_detections
from a3d.runtime.mapping.box_fit import fit_box
from a3d.runtime.postprocess.floor_contact import floor_plane
from a3d.runtime.sources.folder import FolderSource, read_frame
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import backproject_depth
from bench.contact_sheet import contact_sheet
from bench.real_frames import (
    DEFAULT_BOXES,
    DEFAULT_BOXES3D,
    Boxes3D,
    HandBoxes,
    check_frames,
    read_boxes,
    read_boxes3d,
)
from bench.real_frames_views import FrameCloud, draw_frame, found_boxes

FLOOR_GAP_M = 0.04  # points this close above the floor are floor
FLOOR_CLASSES = frozenset(
    {"bed", "bookshelf", "chair", "counter", "desk", "door", "dresser", "lamp", "sofa", "table"}
)
CLUSTER_GAP_M = 0.12  # a jump this large in distance from the camera starts a new cluster
MIN_OBJECT_POINTS = 200  # fewer depth points show too little of an object to fit a box to


# ----------------------------------------------------------------------------- the draft fit


def frame_cloud(frame: Frame, R_tilt: np.ndarray | None = None) -> FrameCloud:
    """The frame's points in the tilt frame of ``R_tilt``, by default the one a3d-run uses for it."""
    if R_tilt is None:
        filled = fill_depth_info(frame.depth).depth
        R_tilt = choose_gravity(frame.depth, filled, frame.intrinsics, frame.R_tilt).R_tilt
    points = backproject_depth(frame.depth, frame.intrinsics) @ R_tilt.T
    valid = frame.depth > 0
    return FrameCloud(R_tilt, points, valid, floor_plane(points[valid]))


def box_points(cloud: FrameCloud, box2d: np.ndarray) -> np.ndarray:
    """Tilt-frame points of the depth pixels inside a 2D box that are not floor."""
    x1, y1, x2, y2 = box2d
    rows = slice(int(np.ceil(y1)), int(np.floor(y2)) + 1)
    cols = slice(int(np.ceil(x1)), int(np.floor(x2)) + 1)
    points = cloud.points[rows, cols][cloud.valid[rows, cols]]
    return points[points[:, 1] < cloud.floor_y(points[:, 0], points[:, 2]) - FLOOR_GAP_M]


def largest_cluster(points: np.ndarray) -> np.ndarray:
    """The largest cluster of points by horizontal distance from the camera: in a 2D box, mostly
    the object rather than what is behind or in front of it."""
    if len(points) == 0:
        return points
    distance = np.hypot(points[:, 0], points[:, 2])
    order = np.argsort(distance)
    clusters = np.split(order, np.flatnonzero(np.diff(distance[order]) > CLUSTER_GAP_M) + 1)
    return points[max(clusters, key=len)]


def fit_object(points: np.ndarray, class_name: str, cloud: FrameCloud) -> np.ndarray:
    """The tilt-frame box of an object's points: ``fit_box`` to a rough box round the bulk of them
    (2nd to 98th percentile), extended down to the floor for a class that stands on it."""
    low, high = np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)
    rough = np.array([*(low + high) / 2, *(high - low)[[0, 2, 1]], 0.0])
    box = fit_box(points, rough, margin_m=0.02)
    if class_name in FLOOR_CLASSES:
        top, bottom = box[1] - box[5] / 2, float(cloud.floor_y(box[0], box[2]))
        box[1], box[5] = (top + bottom) / 2, bottom - top
    return box


def draft(source: FolderSource, hand: dict[str, HandBoxes]) -> dict:
    """The draft boxes file (module docstring): every object fitted or skipped, R_tilt per frame."""
    frames = {}
    for ref in source.refs:
        cloud = frame_cloud(read_frame(ref, source.intrinsics))
        objects, skipped = [], []
        for i, (class_id, box2d) in enumerate(
            zip(hand[ref.name].class_ids, hand[ref.name].boxes, strict=True)
        ):
            name = CLASSES[class_id]
            points = largest_cluster(box_points(cloud, box2d))
            if len(points) < MIN_OBJECT_POINTS:
                skipped.append({"object": i, "class": name, "why": f"{len(points)} depth points in its box"})
                continue
            tilt = fit_object(points, name, cloud)
            box3d = np.array([*(cloud.R_tilt.T @ tilt[:3]), *tilt[3:]])  # the centre back in the camera frame
            objects.append({"object": i, "class": name, "box3d": rounded(box3d)})
        frames[ref.name] = {"R_tilt": cloud.R_tilt.tolist(), "objects": objects, "skipped": skipped}
    return {"about": "a draft (bench.real_frames_fit --fit)", "frames": frames}


def rounded(box3d: np.ndarray) -> list[float]:
    """A box to the millimetre and milliradian, theta towards zero so that it stays in [-pi/2, pi/2]."""
    return [*(round(float(v), 3) for v in box3d[:6]), float(np.trunc(box3d[6] * 1000) / 1000)]


def dump(doc: dict) -> str:
    """A boxes file as JSON with one object per line, so that a hand correction is a one-line diff."""
    lines = ["{", f' "about": {json.dumps(doc["about"])},', ' "frames": {']
    for f, (name, frame) in enumerate(doc["frames"].items()):
        lines += [f"  {json.dumps(name)}: {{", f'   "R_tilt": {json.dumps(frame["R_tilt"])},']
        for key, end in (("objects", ","), ("skipped", "")):
            items = ",\n".join(f"    {json.dumps(item)}" for item in frame[key])
            lines += [f'   "{key}": [', items, f"   ]{end}"] if items else [f'   "{key}": []{end}']
        lines.append("  }," if f < len(doc["frames"]) - 1 else "  }")
    return "\n".join([*lines, " }", "}", ""])


# ----------------------------------------------------------------------------- the command


def draw(
    source: FolderSource,
    hand: dict[str, HandBoxes],
    boxes: dict[str, Boxes3D],
    out: Path,
    detections: dict[str, FrameDetections] | None = None,
    threshold: float = 0.5,
) -> Path:
    """Each frame's picture (bench.real_frames_views) as OUT/NAME.png, each object's as
    OUT/objects/NAME_I.png, and all frames on OUT/real_frames_boxes3d.jpg, a contact sheet at half
    size (the one in docs/images); with ``detections`` (by frame name) the frames' pictures hold
    their boxes scoring ``threshold`` or more, and the sheet is OUT/detections_boxes3d.jpg."""
    (out / "objects").mkdir(parents=True, exist_ok=True)
    tiles = []
    for ref in source.refs:
        frame = read_frame(ref, source.intrinsics)
        truth = boxes[ref.name].truth
        cloud = frame_cloud(frame, truth.R_tilt)
        found = None
        if detections is not None:
            if ref.name not in detections:
                raise InputError(f"the detections file has no line for frame {ref.name}")
            found = found_boxes(detections[ref.name], threshold, truth.R_tilt)
        scene, zoomed = draw_frame(frame, cloud, hand[ref.name], boxes[ref.name], found)
        cv2.imwrite(str(out / f"{ref.name}.png"), scene)
        for i, tile in zip(boxes[ref.name].objects, zoomed, strict=True):
            cv2.imwrite(str(out / "objects" / f"{ref.name}_{i}.png"), tile)
        tiles.append(scene)
    header = "3D boxes of the real frames' hand-drawn objects"
    if detections is not None:
        header += f" (grey) and of the detections >= {threshold:g} (class colours)"
    sheet = contact_sheet(tiles, columns=2, header=header)
    sheet = cv2.resize(sheet, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    path = out / ("real_frames_boxes3d.jpg" if detections is None else "detections_boxes3d.jpg")
    cv2.imwrite(str(path), sheet, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the real frames folder")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--fit", type=Path, metavar="DRAFT", help="write a draft 3D boxes file")
    mode.add_argument("--draw", type=Path, metavar="DIR", help="draw the 3D boxes file's boxes")
    parser.add_argument("--boxes", type=Path, default=DEFAULT_BOXES, help="the hand-drawn 2D boxes file")
    parser.add_argument("--boxes3d", type=Path, default=DEFAULT_BOXES3D, help="the 3D boxes file drawn")
    parser.add_argument("--detections", type=Path, help="with --draw: a run's detections file, drawn too")
    parser.add_argument("--threshold", type=float, default=0.5, help="lowest score of a detection drawn")
    args = parser.parse_args(argv)
    if args.detections and not args.draw:
        parser.error("--detections goes with --draw")
    try:
        hand = read_boxes(args.boxes)
        source = FolderSource(args.folder)
        check_frames(source, hand)
        if args.fit:
            args.fit.write_text(dump(draft(source, hand.frames)))
            print(f"wrote {args.fit}")
        else:
            runs = [] if args.detections is None else read_detections(args.detections)
            found = {d.frame: d for d in runs} if args.detections else None
            boxes3d = read_boxes3d(args.boxes3d, hand)
            print(f"wrote {draw(source, hand.frames, boxes3d, args.draw, found, args.threshold)}")
    except (InputError, ValueError, OSError) as e:
        print(f"real_frames_fit: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
