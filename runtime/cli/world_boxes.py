"""a3d-world-boxes: world_boxes.json for a posed recording, from rough boxes a person types once.

    a3d-world-boxes SOURCE --rough rough.csv [--rough-from map.json] [--out world_boxes.json]
        [--save boxes.rrd | --spawn]

Run it twice. The first time (ROUGH does not exist yet) it fuses the recording's depth into one
coloured point cloud in the recording's world (y down), shows it (``--spawn``: a rerun window;
``--save``: an .rrd to open with ``rerun FILE``) and writes ROUGH, a CSV with the columns to fill
in (a3d.runtime.mapping.rough_boxes): one row per object, its class, centre, size and yaw read off
the view, a hand's width off is fine; with ``--rough-from MAP.json`` (``a3d-run SOURCE --map
MAP.json``) ROUGH starts with a row per object a3d found in the recording, for the person to
correct rather than type. The second time it fits every rough box to the points inside
it (a3d.runtime.mapping.box_fit, the floor found and left out), writes OUT for a3d-labels, and
shows the fitted boxes over the cloud and, as PNGs in CHECK_DIR (and in the view), over a few
frames: the check that each box sits on its object. Bad input (a source without poses, a class
outside the 19, a rough box around nothing) is one line and exit 2, before anything is written.
docs/mapping.md "Drawing the world boxes for your own recording".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.cli.labels import add_source_args, open_posed_source
from a3d.runtime.errors import InputError
from a3d.runtime.extras import Needs
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.mapping.box_fit import DepthView, Fitted, fitted_box, floor_level, world_cloud
from a3d.runtime.mapping.labels import LabelConfig, inside_box
from a3d.runtime.mapping.object_map import read_confirmed
from a3d.runtime.mapping.rough_boxes import RoughBoxes, read_rough_boxes, write_template
from a3d.runtime.mapping.world import boxes_to_camera, rtilt_from_pose
from a3d.runtime.mapping.world_boxes import WORLD_BOXES_FILE, WorldBoxes, write_world_boxes
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, CLASSES
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import BOX_EDGES
from a3d.runtime.viewer.options import load_view
from a3d.runtime.viewer.shapes import projected_box_edges

PROG = "a3d-world-boxes"
VIEW_VOXEL_M = 0.02  # the cloud shown is thinned to one point per 2 cm cube


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument(
        "source", type=Path, help="a posed frame source (poses in a gravity-aligned world, y down)"
    )
    p.add_argument(
        "--rough", type=Path, required=True, help="rough boxes CSV: a template is written when missing"
    )
    p.add_argument(
        "--rough-from", type=Path, metavar="MAP.json",
        help="fill a new ROUGH with the confirmed objects of an object map (a3d-run --map), to correct",
    )  # fmt: skip
    p.add_argument("--out", type=Path, help=f"the fitted boxes (default: {WORLD_BOXES_FILE} beside ROUGH)")
    p.add_argument("--check-dir", type=Path, help="the check images (default: OUT without .json, + _check)")
    p.add_argument("--check-frames", type=int, default=4, help="frames the fitted boxes are drawn over")
    p.add_argument("--stride", type=int, default=4, help="every STRIDE-th pixel each way goes into the cloud")
    p.add_argument("--frame-step", type=int, default=1, help="every FRAME-STEP-th frame goes into the cloud")
    p.add_argument("--margin", type=float, default=0.1, help="metres a rough box grows to catch its object")
    shown = p.add_mutually_exclusive_group()
    shown.add_argument("--save", type=Path, metavar="FILE.rrd", help="record the view to this .rrd file")
    shown.add_argument("--spawn", action="store_true", help="show the view in a rerun window")
    add_source_args(p)
    return p


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if min(args.stride, args.frame_step) < 1 or args.check_frames < 0 or args.margin < 0:
        parser.error("--stride and --frame-step must be >= 1, --check-frames and --margin >= 0")
    if args.save or args.spawn:
        Needs("view", ("rerun",)).check()
    if args.rough_from is not None and args.rough.exists():
        raise InputError(f"{args.rough}: exists; --rough-from only fills a new rough boxes file")
    proposed = proposals(args.rough_from) if args.rough_from is not None else []
    rough = read_rough_boxes(args.rough) if args.rough.exists() else None  # bad rows before any work
    loaders = list(open_posed_source(args))
    fused = loaders[:: args.frame_step]
    cloud = world_cloud(_loaded(fused), args.stride)
    points, colours = cloud.points, cloud.colours
    if not len(points):
        raise InputError(f"{args.source}: no frame has a pose; a3d-world-boxes needs a posed recording "
                         "(docs/sources.md 'Camera poses')")  # fmt: skip
    floor = floor_level(points)
    _say(f"{len(points)} world points from {len(fused)} frames; the floor at y = {floor:.3f} m")
    if rough is None:
        extent = np.percentile(points, [1, 99], axis=0).round(2)
        write_template(args.rough, [
            f"The cloud spans x {extent[0, 0]} .. {extent[1, 0]}, z {extent[0, 2]} .. {extent[1, 2]}; "
            f"the floor is at y = {floor:.2f}.",
            *([f"The rows below are the objects of {args.rough_from}: delete the wrong ones, correct the "
               "rest, add what it missed."] if args.rough_from else []),
        ], proposed)  # fmt: skip
        shown = RoughBoxes([row[1] for row in proposed], np.array([row[2] for row in proposed]), [])
        _show(args, points, colours, shown if proposed else None, None, [])
        todo = "add one row per object (read off the view)"
        if args.rough_from:
            todo = f"correct the {len(proposed)} rows from {args.rough_from}, add what it missed"
        _say(f"wrote {args.rough}: {todo}, then run this again")
        return 0
    out = args.out or args.rough.parent / WORLD_BOXES_FILE
    fitted, fits = fit_all(points, rough, args.margin, floor, args.rough, cloud.views)
    write_world_boxes(out, fitted)
    for k, line in enumerate(rough.lines):
        moved = fitted.boxes[k, :3] - rough.boxes[k, :3]
        _say(f"{args.rough}:{line} {rough.classes[k]}: fitted {np.round(fitted.boxes[k], 3).tolist()} "
             f"(centre moved {np.linalg.norm(moved):.3f} m{_kept_text(fits[k])})")  # fmt: skip
    check_dir = args.check_dir or out.with_name(out.stem + "_check")
    checks = check_images(loaders, fitted, check_dir, args.check_frames)
    _show(args, points, colours, rough, fitted, checks)
    _say(f"wrote {out} ({len(fitted)} objects) and {len(checks)} check images in {check_dir}")
    return 0


def _kept_text(fit: Fitted) -> str:
    """What the fit kept of the rough box and why, for the box's line ("" for nothing)."""
    kept = []
    if fit.unseen:
        kept.append(f"kept the rough box's {_faces_text(fit.unseen)}: no frame saw past the points")
    if fit.part_seen:
        sides = 2 * fit.part_seen
        kept.append(f"kept the rough box's {sides} sides: the points span under half the way between them")
    return "".join(f"; {text}" for text in kept)


def _faces_text(faces: tuple[str, ...]) -> str:
    """("top", "side", "side") as "top and 2 sides"."""
    sides = faces.count("side")
    named = [face for face in faces if face != "side"]
    named += ["side"] if sides == 1 else [f"{sides} sides"] if sides else []
    return " and ".join(named)


def proposals(path: Path) -> list[tuple[str, str, np.ndarray]]:
    """The object map's confirmed objects as rough boxes' rows (a comment, a class, a box), the
    surest first: what a3d itself found in the recording, for the person to correct."""
    found = read_confirmed(path)
    order = np.argsort(-found.scores, kind="stable")
    return [
        (f"{path.name}: score {found.scores[k]:.2f}, detected in {found.support[k]} frames",
         found.classes[k], found.boxes[k])
        for k in order
    ]  # fmt: skip


def fit_all(
    points: np.ndarray,
    rough: RoughBoxes,
    margin: float,
    floor: float | None,
    path: Path,
    views: list[DepthView] | None = None,
) -> tuple[WorldBoxes, list[Fitted]]:
    """Every rough box fitted to its points (InputError naming the file's line for one around too few), and
    per box its fit with what it kept of the rough box (``box_fit.fitted_box``). A box's margin does
    not reach into its neighbours: points inside another rough box and not inside its own are left
    out (the sofa under a pillow, the table beside a chair)."""
    tight = LabelConfig(margin_m=0.0, floor_gap_m=0.0)
    owner = np.stack([inside_box(points, box, np.eye(3), tight) for box in rough.boxes])
    fits = []
    for k, line in enumerate(rough.lines):
        others = np.delete(owner, k, axis=0).any(axis=0) & ~owner[k]
        try:
            fits.append(fitted_box(points[~others], rough.boxes[k], margin, floor, views))
        except InputError as e:
            raise InputError(f"{path}:{line}: {rough.classes[k]}: {e}") from None
    boxes = np.array([fit.box for fit in fits])
    world = WorldBoxes(list(rough.classes), boxes, np.arange(len(boxes), dtype=np.int64))
    return world, fits


def check_images(loaders: list, fitted: WorldBoxes, folder: Path, count: int) -> list[tuple[str, np.ndarray]]:
    """``count`` posed frames spread over the recording with the fitted boxes drawn (RGB), written
    as FOLDER/NAME.png."""
    chosen = np.unique(np.linspace(0, len(loaders) - 1, count).round().astype(int)) if count else []
    drawn = []
    for frame in _loaded([loaders[i] for i in chosen]):
        if frame.pose is not None:
            image = draw_world_boxes(frame, fitted)
            atomic_write_bytes(
                folder / f"{frame.name}.png", cv2.imencode(".png", image[:, :, ::-1])[1].tobytes()
            )
            drawn.append((frame.name, image))
    return drawn


def draw_world_boxes(frame: Frame, world: WorldBoxes) -> np.ndarray:
    """The frame's colour (RGB) with the world boxes' edges projected into it, labelled "class #id"."""
    assert frame.pose is not None
    R_tilt = rtilt_from_pose(frame.pose)
    image = np.ascontiguousarray(frame.color[:, :, ::-1])
    segments = projected_box_edges(boxes_to_camera(world.boxes, frame.pose, R_tilt), R_tilt, frame.intrinsics,
                                   frame.image_size)  # fmt: skip
    for k, name in enumerate(world.classes):
        colour = CLASS_COLORS_RGB[CLASSES.index(name)]
        edges = segments[k * len(BOX_EDGES) : (k + 1) * len(BOX_EDGES)]
        edges = edges[np.isfinite(edges).all(axis=(1, 2))]
        for a, b in edges.round().astype(int):
            cv2.line(image, tuple(a), tuple(b), colour, 1, cv2.LINE_AA)
        if len(edges):
            x, y = edges.reshape(-1, 2).min(axis=0)
            cv2.putText(image, f"{name} #{world.ids[k]}", (int(x), max(int(y) - 3, 10)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv2.LINE_AA)  # fmt: skip
    return image


def _show(args: argparse.Namespace, points: np.ndarray, colours: np.ndarray, rough: RoughBoxes | None,
          fitted: WorldBoxes | None, checks: list[tuple[str, np.ndarray]]) -> None:  # fmt: skip
    """The cloud (thinned to a point per ``VIEW_VOXEL_M`` cube), the rough and the fitted boxes in
    the world, and the check images, to --save or --spawn."""
    if not (args.save or args.spawn):
        return
    view = load_view()
    import rerun as rr  # the view extra, checked with the flags

    rec = rr.RecordingStream(f"{view.APPLICATION_ID}-world-boxes")
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        rec.save(args.save)
    else:
        rec.spawn()
    view.log_static(rec)
    keep = np.unique(np.floor(points / VIEW_VOXEL_M).astype(np.int64), axis=0, return_index=True)[1]
    rec.log("world/points", rr.Points3D(points[keep], colors=colours[keep], radii=0.008), static=True)
    for entity, boxes, what in (("world/rough", rough, "rough"), ("world/fitted", fitted, "")):
        if boxes is not None:
            ids = np.array([CLASSES.index(name) for name in boxes.classes])
            labels = [f"{what} {name}".strip() for name in boxes.classes]
            rec.log(entity, view.boxes3d_archetype(boxes.boxes, np.eye(3), ids, labels), static=True)
    for name, image in checks:
        rec.log(f"check/{name}", rr.Image(image), static=True)
    rr.disconnect(rec)
    if args.save:
        _say(f"wrote {args.save} (open it with: rerun {args.save})")


def _loaded(loaders: list):
    """The loaders' frames, one at a time (a recording's frames need not fit in memory together)."""
    for loader in loaders:
        yield loader.load()


def _say(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
