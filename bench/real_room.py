"""Your own room, on real frames: poses, world boxes and labels for real views of one room.

    .venv/bin/python -m bench.real_room REAL_FRAMES --work WORK [--finetune [--minutes 15] [--iters N]]

No real posed recording with 3D ground truth can be had here. Two rooms of REAL_FRAMES stand in
for one, each a few real Kinect views without poses, with their drawn-once 3D boxes
(bench/data/real_frames_boxes3d.json, each fitted to its own view's depth alone): a dining and
living room (slambook_ch5_1 to _5, a metre or so and 15 to 25 degrees apart) and an office desk
(slambook_ch7_1, _2). The bench runs what a user runs on such a recording, as subprocesses, for
each room in WORK/ROOM:

1. ``a3d-poses`` on the views: which it tracked, which image features placed
   (a3d.runtime.mapping.relocalise), and the share of the model each one's depth confirms;
2. the drawn-once boxes of each view, moved into the tracked world, grouped into objects (same
   class, centres within 0.4 m: the same chair seen from two views): how far one object's boxes
   from different views lie apart. No true poses exist; boxes fitted to each view's depth alone that
   land on each other say the poses are right, to within the fits' own spread;
3. ``a3d-world-boxes`` from rough boxes (each object's first drawn-once box in the world, moved,
   scaled and turned as bench.own_room makes a person's rough boxes), fitted to the views' cloud:
   each fitted box taken into every view that has the object, against that view's drawn-once box
   (3D IoU, centre distance), the rough box's IoU beside it;
4. ``a3d-labels`` from the fitted boxes: every view's ground truth, WORK/ROOM/labelled;
5. with ``--finetune``: ``a3d-finetune`` of ``real`` on the dining room's first three views
   (``--holdout 0.4``), and ``real`` against the fine-tuned model on its last two, through a3d-run
   + a3d-eval against their labels. Two views of a handful of objects: a demonstration that the
   chain runs on real frames, not a measure of the gain.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.mapping.box_fit import floor_level, world_cloud
from a3d.runtime.mapping.rough_boxes import read_rough_boxes
from a3d.runtime.mapping.world import boxes_to_camera, boxes_to_world
from a3d.runtime.mapping.world_boxes import WorldBoxes, read_world_boxes, write_world_boxes
from a3d.runtime.sources.folder import TRACKING_FILE, FolderSource, list_frames, read_meta
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, CLASSES, class_index
from a3d.runtime.structures.geometry import (
    box_corners_tilt,
    iou_3d,
)
from bench.own_room import load, rough_csv, scores, sh
from bench.real_frames import DEFAULT_BOXES, DEFAULT_BOXES3D, read_boxes, read_boxes3d
from bench.real_frames_views import FrameCloud, Outlines, top_view

ROOMS = {
    "dining": tuple(f"slambook_ch5_{i}" for i in range(1, 6)),  # a dining and living room, five views
    "desk": ("slambook_ch7_1", "slambook_ch7_2"),  # an office desk, two views
}
SAME_OBJECT_M = 0.4


@dataclass
class View:
    """One drawn-once box of one view: the view, its class, its box in the view's camera (tilt
    frame ``R_tilt``) and in the world."""

    frame: str
    name: str
    camera_box: np.ndarray
    R_tilt: np.ndarray
    world_box: np.ndarray


def link(folder: Path, room: tuple[str, ...], out: Path) -> None:
    """The room's views of ``folder``, as links in ``out`` (no poses: the source as it is)."""
    out.mkdir(parents=True, exist_ok=True)
    for name in room:
        for path in sorted(folder.glob(f"{name}.*")):
            target = out / path.name
            if not target.exists():
                target.symlink_to(path.resolve())


def tracking(posed: Path) -> None:
    """Step 1's table."""
    print("| view | tracked | placed by image features | share of the model its depth confirms |")
    print("| --- | --- | --- | ---: |")
    for line in (posed / TRACKING_FILE).read_text().splitlines():
        r = json.loads(line)
        print(f"| {r['frame']} | {r['tracked']} | {r.get('relocalised', False)} | {r['agreement']:.2f} |")


def views_in_world(posed: Path) -> list[View]:
    """Every drawn-once 3D box of the posed views, with its box in the tracked world."""
    boxes3d = read_boxes3d(DEFAULT_BOXES3D, read_boxes(DEFAULT_BOXES))
    poses = {ref.name: read_meta(ref).pose for ref in list_frames(posed)}
    out = []
    for frame in sorted(poses):
        truth = boxes3d[frame].truth
        world = boxes_to_world(truth.boxes3d, truth.R_tilt, poses[frame])
        for class_id, box, in_world in zip(truth.class_ids, truth.boxes3d, world, strict=True):
            out.append(View(frame, CLASSES[class_id], box, truth.R_tilt, in_world))
    return out


def group(views: list[View]) -> list[list[View]]:
    """The views' boxes grouped into objects: each joins the first object of its class whose first
    box's centre lies within SAME_OBJECT_M, else starts one."""
    objects: list[list[View]] = []
    for view in views:
        for seen in objects:
            if (
                seen[0].name == view.name
                and np.linalg.norm(seen[0].world_box[:3] - view.world_box[:3]) < SAME_OBJECT_M
            ):
                seen.append(view)
                break
        else:
            objects.append([view])
    return objects


def consistency(objects: list[list[View]]) -> None:
    """Step 2's table: per object seen in two views or more, its boxes' centres' spread."""
    print("| object | views | centres apart: median, largest (cm) |")
    print("| --- | --- | ---: |")
    apart_all = []
    for k, views in enumerate(objects):
        if len(views) < 2:
            continue
        centres = np.array([v.world_box[:3] for v in views])
        apart = [np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[i + 1 :]]
        apart_all += apart
        frames = ", ".join(v.frame.rsplit("_", 1)[1] for v in views)
        print(f"| {k}: {views[0].name} | {frames} | {100 * np.median(apart):.0f}, {100 * max(apart):.0f} |")
    print(
        f"| **all pairs** | {len(apart_all)} | {100 * np.median(apart_all):.0f}, {100 * max(apart_all):.0f} |"
    )


def world_boxes(objects: list[list[View]], posed: Path, boxes: Path) -> None:
    """Step 3: rough boxes, a3d-world-boxes, and its table."""
    boxes.mkdir(parents=True, exist_ok=True)
    first = WorldBoxes([o[0].name for o in objects], np.array([o[0].world_box for o in objects]),
                       np.arange(len(objects)))  # fmt: skip
    write_world_boxes(boxes / "drawn_once.json", first)
    (boxes / "rough.csv").write_text(rough_csv(boxes / "drawn_once.json"))
    seconds = sh("a3d-world-boxes", posed, "--rough", boxes / "rough.csv", "--save", boxes / "fitted.rrd")
    fitted, rough = read_world_boxes(boxes / "world_boxes.json"), read_rough_boxes(boxes / "rough.csv").boxes
    poses = {ref.name: read_meta(ref).pose for ref in list_frames(posed)}
    print(f"\n## a3d-world-boxes ({seconds:.0f} s, {load()})\n")
    print("| object | views | 3D IoU with each view's drawn-once box, rough -> fitted | centre off (cm) |")
    print("| --- | ---: | --- | ---: |")
    rows = []
    for k, views in enumerate(objects):
        ious, offs = [], []
        for view in views:
            truth = view.camera_box[None]
            pair = [
                boxes_to_camera(b[None], poses[view.frame], view.R_tilt) for b in (rough[k], fitted.boxes[k])
            ]
            ious.append([iou_3d(truth, b, view.R_tilt)[0, 0] for b in pair])
            offs.append(np.linalg.norm(pair[1][0, :3] - truth[0, :3]))
        before, after = np.median(ious, axis=0)
        rows.append((before, after, np.median(offs)))
        off = 100 * np.median(offs)
        print(f"| {k}: {views[0].name} | {len(views)} | {before:.2f} -> {after:.2f} (medians) | {off:.0f} |")
    before, after, off = np.median(rows, axis=0)
    print(f"| **median** | {len(rows)} objects | {before:.2f} -> {after:.2f} | {100 * off:.0f} |")


def finetune(work: Path, minutes: str, iters: str | None) -> None:
    """Step 5: a3d-finetune on the room's first three views; real and the new model on the last two."""
    model = work / "ft.onnx"
    extra = ["--iters", iters] if iters else []
    seconds = sh("a3d-finetune", work / "labelled", "--out", model, "--holdout", "0.4", "--minutes", minutes,
                 *extra)  # fmt: skip
    holdout = work / "ft.finetune" / "holdout"
    before, after = (
        scores(m, holdout, work / f"eval_{n}")["map"]["0.25"]["present_classes"]
        for m, n in (("real", "real"), (model, "ft"))
    )
    print(f"\n## a3d-finetune ({seconds / 60:.1f} min, {load()}): the last two views' mAP@0.25 against their "
          f"labels (their classes): real {100 * before:.1f} -> fine-tuned {100 * after:.1f}")  # fmt: skip


def draw(objects: list[list[View]], posed: Path, boxes: Path, out: Path) -> None:
    """The views' fused points from above, with each object's rough box (white), fitted box (its
    class colour, labelled) and first drawn-once box (grey): OUT (an image file)."""
    cloud = world_cloud([loader.load() for loader in FolderSource(posed)])
    floor = floor_level(cloud.points)
    floor = cloud.points[:, 1].max() if floor is None else floor
    frame = FrameCloud(
        np.eye(3), cloud.points[:, None], np.ones((len(cloud.points), 1), bool), np.array([0, 0, floor])
    )
    fitted = read_world_boxes(boxes / "world_boxes.json")
    parts = [
        (np.array([o[0].world_box for o in objects]), (150, 150, 150), ["" for _ in objects]),
        (read_rough_boxes(boxes / "rough.csv").boxes, (255, 255, 255), ["" for _ in objects]),
        (fitted.boxes, None, [f"{k}: {name}" for k, name in enumerate(fitted.classes)]),
    ]
    outlines = [
        Outlines(
            box_corners_tilt(b, np.eye(3)),
            [colour or CLASS_COLORS_RGB[class_index(n)][::-1] for n in fitted.classes],
            labels,
        )
        for b, colour, labels in parts
    ]
    cv2.imwrite(str(out), top_view(frame, cloud.points, sum(outlines[1:], outlines[0]), 720))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="the real frames folder (with slambook_ch5_* and _ch7_*)")
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--finetune", action="store_true", help="step 5, on the dining room")
    parser.add_argument("--minutes", default="15")
    parser.add_argument("--iters", help="a3d-finetune --iters (default: its recipe's)")
    args = parser.parse_args(argv)
    for name, room in ROOMS.items():
        work = args.work / name
        link(args.folder, room, work / "recording")
        posed = work / "posed"
        print(f"# {name}: {len(room)} views\n")
        if not posed.exists():
            print(f"## a3d-poses: {sh('a3d-poses', work / 'recording', '--out', posed):.1f} s\n")
        tracking(posed)
        objects = group(views_in_world(posed))
        print(f"\n## The drawn-once boxes in the tracked world: {len(objects)} objects\n")
        consistency(objects)
        world_boxes(objects, posed, work / "boxes")
        draw(objects, posed, work / "boxes", work / "room.jpg")
        print(f"\nwrote {work / 'room.jpg'}: from above, drawn once grey, rough white, fitted in colour")
        labelled = work / "labelled"
        shutil.rmtree(labelled, ignore_errors=True)  # the boxes were fitted again
        sh("a3d-labels", work / "boxes" / "world_boxes.json", posed, "--out", labelled)
    if args.finetune:
        finetune(args.work / "dining", args.minutes, args.iters)
    return 0


if __name__ == "__main__":
    sys.exit(main())
