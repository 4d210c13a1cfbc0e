"""Poses from the depth (a3d-poses) on a synthetic recording, against the poses it was rendered at.

    .venv/bin/python -m bench.poses SEQ --work WORK [--every 4] [--voxel M]
        [--finetune [--seeds 0,1] [--minutes 15]] [--map]

SEQ is an ``a3d-synth --sequence`` folder (frames with their true poses, world_boxes.json). The
bench runs what a user with a RealSense alone runs, as subprocesses, and measures each step
against the truth:

1. WORK/recording: SEQ's frames without their poses and R_tilt (intrinsics only);
2. ``a3d-poses WORK/recording --out WORK/posed --every N``: the wall time; the estimated path
   against the true one after the rigid fit that best maps one onto the other (the estimated
   world's origin and heading are the first camera's): position error (median, largest), rotation
   error, and each frame's gravity (its R_tilt from the estimated pose against the true one);
3. ``a3d-world-boxes`` from rough boxes, as bench.own_room makes them, in the estimated world:
   the room's boxes moved to where the tracked recording shows them (``boxes_where_seen``: each
   through the frames that see it), as a person drawing them in its fused cloud sees them; and on
   the same frames with their own poses;
4. ``a3d-labels`` with the estimated poses: each frame's labels against its true ground truth
   (the label of the same class that overlaps a true object most): the share of the true objects
   labelled at 3D IoU >= 0.5 and >= 0.25, and the median IoU;
5. with ``--finetune``: ``a3d-finetune`` (``--holdout 0.4``) on those labels and, beside it, on
   the same frames labelled from the sequence's own poses, once per ``--seeds`` seed; ``real`` and
   every fine-tuned model run on the frames both held back, with their *true* labels (``a3d-run``
   + ``a3d-eval``): AP@0.25 per class;
6. with ``--map``: ``a3d-run --map`` on the recording's every N-th frame without poses (each
   tracked as the run reads it, a3d.runtime.mapping.tracked_poses) and on the same frames with
   their own poses and gravity: each run's wall time, the poses it tracked against the true path
   (as in step 2), and each map projected back into the frames against their true labels
   (bench.map_consistency).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from a3d.runtime.evaluation.metric import retilt_boxes
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.mapping.odometry import TrackerConfig
from a3d.runtime.mapping.world_boxes import read_world_boxes, write_world_boxes
from a3d.runtime.sources.folder import LABELS_FILE, TRACKING_FILE, list_frames, read_ground_truth, read_meta
from a3d.runtime.structures.geometry import box_corners_camera, boxes_from_corners_tilt, iou_3d
from a3d.runtime.structures.pose import invert_pose, rigid_fit, rotation_deg, transform_points
from bench import map_consistency
from bench.own_room import BIN, load, scores, sh, world_boxes_step


def strip_poses(frames: Path, out: Path) -> None:
    """``frames`` as a RealSense alone records them: colour and depth linked, meta.json with the
    intrinsics only."""
    out.mkdir(parents=True, exist_ok=True)
    if (frames / "intrinsics.json").is_file():
        shutil.copy(frames / "intrinsics.json", out / "intrinsics.json")
    for ref in list_frames(frames):
        for path in (ref.color_path, ref.depth_path):
            link = out / path.name
            if not link.exists():
                link.symlink_to(path.resolve())
        meta = read_meta(ref)
        if meta.intrinsics is not None:
            K = meta.intrinsics
            document = {"intrinsics": {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy}}
            (out / f"{ref.name}.meta.json").write_text(json.dumps(document))


def path_errors(seq_frames: Path, posed: Path) -> tuple[np.ndarray, dict[str, float]]:
    """The fit taking the true world to the estimated one, and the path's errors (module docstring)."""
    metas = {ref.name: read_meta(ref) for ref in list_frames(posed)}
    return path_errors_of(seq_frames, {name: (meta.pose, meta.R_tilt) for name, meta in metas.items()})


def path_errors_of(
    seq_frames: Path, est: dict[str, tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, dict[str, float]]:
    """``path_errors`` of the estimated (pose, R_tilt) of each named frame."""
    true = {ref.name: read_meta(ref) for ref in list_frames(seq_frames)}
    names = sorted(est)
    T_true = np.array([true[n].pose for n in names])
    T_est = np.array([est[n][0] for n in names])
    fit = rigid_fit(T_true[:, :3, 3], T_est[:, :3, 3])
    moved = np.einsum("ij,njk->nik", fit, T_true)
    position = np.linalg.norm(moved[:, :3, 3] - T_est[:, :3, 3], axis=1)
    rotation = [rotation_deg(a[:3, :3].T @ b[:3, :3]) for a, b in zip(moved, T_est, strict=True)]
    gravity = [math.degrees(math.acos(np.clip(true[n].R_tilt[1] @ est[n][1][1], -1.0, 1.0))) for n in names]
    steps = np.linalg.norm(np.diff(T_true[:, :3, 3], axis=0), axis=1)
    return fit, {
        "frames": len(names),
        "path_m": float(steps.sum()),
        "position_median_cm": 100 * float(np.median(position)),
        "position_max_cm": 100 * float(position.max()),
        "rotation_median_deg": float(np.median(rotation)),
        "rotation_max_deg": float(np.max(rotation)),
        "gravity_median_deg": float(np.median(gravity)),
        "gravity_max_deg": float(np.max(gravity)),
    }


def boxes_where_seen(
    boxes: np.ndarray, ids: np.ndarray, true_frames: Path, posed: Path, true_labelled: Path, fit: np.ndarray
) -> np.ndarray:
    """The world boxes (N, 7) where the tracked recording shows each object: its corners taken
    through every frame that sees it (true labels' labels.jsonl) from the true camera to the tracked
    one, and averaged; ``fit`` (the path's rigid fit) for an object no tracked frame sees. A person
    drawing the boxes in the tracked cloud sees them there, whatever the drift between rooms' ends."""
    true = {ref.name: read_meta(ref).pose for ref in list_frames(true_frames)}
    est = {ref.name: read_meta(ref).pose for ref in list_frames(posed)}
    seen: dict[int, list[str]] = {}
    for line in (true_labelled / LABELS_FILE).read_text().splitlines():
        record = json.loads(line)
        for obj in record["objects"]:
            if obj["labelled"] and record["frame"] in est:
                seen.setdefault(obj["id"], []).append(record["frame"])
    out = []
    for box, object_id in zip(boxes, ids, strict=True):
        corners = box_corners_camera(box[None], np.eye(3))[0]
        moves = [est[n] @ invert_pose(true[n]) for n in seen.get(int(object_id), [])] or [fit]
        mean = np.mean([transform_points(move, corners) for move in moves], axis=0)
        out.append(boxes_from_corners_tilt(mean[None], np.eye(3))[0])
    return np.array(out).reshape(-1, 7)


def label_agreement(seq_frames: Path, labelled: Path) -> dict[str, dict[str, float]]:
    """Each true object of every labelled frame against the frame's label of its class that
    overlaps it most (3D IoU in the true frame's tilt frame; 0 where there is none): over all
    objects ("all") and per class, the count, the median IoU and the shares at 0.5 and 0.25."""
    true = {ref.name: ref for ref in list_frames(seq_frames)}
    ious: dict[str, list[float]] = {}
    for ref in list_frames(labelled):
        truth, labels = read_ground_truth(true[ref.name]), read_ground_truth(ref)
        R_true, R_label = read_meta(true[ref.name]).R_tilt, read_meta(ref).R_tilt
        boxes = retilt_boxes(labels.boxes3d, R_label, R_true)
        for name, cls, box in zip(truth.classes, truth.class_ids, truth.boxes3d, strict=True):
            same = boxes[labels.class_ids == cls]
            iou = float(iou_3d(box[None], same, R_true).max()) if len(same) else 0.0
            for key in ("all", name):
                ious.setdefault(key, []).append(iou)
    return {
        key: {
            "objects": len(values),
            "iou_median": round(float(np.median(values)), 3),
            "share_iou_0.5": round(float(np.mean(np.array(values) >= 0.5)), 4),
            "share_iou_0.25": round(float(np.mean(np.array(values) >= 0.25)), 4),
        }
        for key, values in ious.items()
    }


def link_frames(frames: Path, names: set[str], out: Path) -> None:
    """A frame folder of the named frames of ``frames`` (links, their intrinsics.json too)."""
    out.mkdir(parents=True, exist_ok=True)
    for path in frames.iterdir():
        if (path.name.split(".")[0] in names or path.name == "intrinsics.json") and not (
            out / path.name
        ).exists():
            (out / path.name).symlink_to(path.resolve())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("seq", type=Path, help="an a3d-synth --sequence folder")
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--every", type=int, default=4, help="a3d-poses --every")
    p.add_argument("--voxel", type=float, default=TrackerConfig().voxel_m, help="a3d-poses --voxel")
    p.add_argument("--finetune", action="store_true", help="also fine-tune on the labels (step 5)")
    p.add_argument("--seeds", default="0", help="step 5's fine-tunes' seeds (solver.seed), comma-separated")
    p.add_argument("--minutes", type=float, default=15.0)
    p.add_argument(
        "--map", action="store_true", help="also a3d-run --map without poses and with them (step 6)"
    )
    args = p.parse_args(argv)
    posed = track(args)
    fit, path = path_errors(args.seq / "frames", posed)
    print("\n" + json.dumps({"path": path}, indent=1))
    true_seq = args.work / "true_seq"  # the same frames with the sequence's own poses, for comparison
    link_frames(
        args.seq / "frames",
        {r.name for r in list_frames(args.seq / "frames")[:: args.every]},
        true_seq / "frames",
    )
    if not (true_seq / "world_boxes.json").exists():
        (true_seq / "world_boxes.json").symlink_to((args.seq / "world_boxes.json").resolve())
    true_labelled = args.work / "true_labelled"
    if not true_labelled.is_dir():
        sh("a3d-labels", true_seq / "world_boxes.json", true_seq / "frames", "--out", true_labelled)
    est = args.work / "est"
    est.mkdir(parents=True, exist_ok=True)
    world = read_world_boxes(args.seq / "world_boxes.json")
    moved = boxes_where_seen(world.boxes, world.ids, true_seq / "frames", posed, true_labelled, fit)
    write_world_boxes(est / "world_boxes.json", type(world)(world.classes, moved, world.ids))
    if not (est / "frames").exists():
        (est / "frames").symlink_to(posed.resolve())
    for title, seq, work in (("tracked", est, args.work), ("sequence's own", true_seq, true_seq)):
        print(f"\n### World boxes on the {title} poses")
        world_boxes_step(seq, work)
    labelled = args.work / "labelled"
    if not labelled.is_dir():
        sh("a3d-labels", est / "world_boxes.json", posed, "--out", labelled)
    print("\n" + json.dumps({"labels": label_agreement(args.seq / "frames", labelled)}, indent=1))
    if args.finetune:
        finetunes(args, labelled, true_seq)
    if args.map:
        maps(args, true_seq / "frames")
    return 0


def maps(args: argparse.Namespace, true_frames: Path) -> None:
    """Step 6 (module docstring): ``true_frames`` are the every N-th frames with their own poses."""
    unposed = args.work / "map_recording"
    link_frames(args.work / "recording", {ref.name for ref in list_frames(true_frames)}, unposed)
    for tag, frames in (("tracked", unposed), ("true", true_frames)):
        detections = args.work / f"map_{tag}.jsonl"
        before = load()
        seconds = sh(
            "a3d-run", frames, "--headless", "--output", detections, "--map", args.work / f"map_{tag}.json"
        )
        lines = read_detections(detections)
        print(f"\n## a3d-run --map, {tag} poses: {len(lines)} frames in {seconds:.0f} s "
              f"({len(lines) / seconds:.2f} frames/s); before: {before}; after: {load()}")  # fmt: skip
        if tag == "tracked":
            est = {line.frame: (line.pose, line.R_tilt) for line in lines if line.pose is not None}
            print(json.dumps({"tracked path": path_errors_of(args.seq / "frames", est)[1]}, indent=1))
        map_consistency.main([str(true_frames), "--detections", str(detections)])


def track(args: argparse.Namespace) -> Path:
    """Steps 1 and 2 (module docstring): WORK/posed, its wall time and what it could not track."""
    recording, posed = args.work / "recording", args.work / "posed"
    strip_poses(args.seq / "frames", recording)
    if not posed.is_dir():
        before, start = load(), time.perf_counter()
        words = [
            BIN / "a3d-poses",
            recording,
            "--out",
            posed,
            "--every",
            str(args.every),
            "--voxel",
            str(args.voxel),
        ]
        code = subprocess.run(words, stdout=sys.stderr).returncode  # 1: frames it could not track
        if code not in (0, 1):
            raise SystemExit(f"a3d-poses exited {code}")
        seconds = time.perf_counter() - start
        print(f"\n## a3d-poses --every {args.every}: {seconds:.0f} s; before: {before}; after: {load()}")
    records = [json.loads(line) for line in (posed / TRACKING_FILE).read_text().splitlines()]
    lost = [r["frame"] for r in records if not r["tracked"]]
    print(
        f"\n{len(records) - len(lost)} of {len(records)} frames tracked"
        + (f"; not: {', '.join(lost)}" if lost else "")
    )
    return posed


def finetunes(args: argparse.Namespace, labelled: Path, true_seq: Path) -> None:
    """Step 5: a3d-finetune on the tracked poses' labels and, beside it, on the labels of the same
    frames from the sequence's own poses (``true_seq``), once per seed; `real` and every model
    scored on the frames that both held back, with their true labels, per class, and the network
    alone (``--detector none``)."""
    true_labelled = args.work / "true_labelled"
    models: dict[str, Path] = {"real": Path("real")}
    held: set[str] | None = None
    for tag, folder in (("tracked", labelled), ("true", true_labelled)):
        work = args.work / f"ft_{tag}.finetune"
        for seed in args.seeds.split(","):
            model = models.setdefault(f"{tag} poses, seed {seed}", args.work / f"ft_{tag}_s{seed}.onnx")
            if not model.is_file():
                before = load()
                seconds = sh("a3d-finetune", folder, "--out", model, "--work", work, "--minutes",
                             args.minutes, "--holdout", "0.4", "--set", f"solver.seed={seed}")  # fmt: skip
                took = f"{seconds / 60:.1f} minutes; before: {before}; after: {load()}"
                print(f"\n## a3d-finetune ({tag} poses, seed {seed}): {took}")
        names = {ref.name.split("_", 1)[1] for ref in list_frames(work / "holdout")}  # "r0_NAME"
        held = names if held is None else held & names
    truth = args.work / "holdout_truth"
    link_frames(args.seq / "frames", held or set(), truth)
    reports = {tag: scores(model, truth, args.work / f"eval_{model.stem}") for tag, model in models.items()}
    alone = {
        tag: scores(model, truth, args.work / f"eval_alone_{model.stem}", "--detector", "none")
        for tag, model in models.items()
    }
    classes = reports["real"]["present_classes"]
    print(f"\n{len(held or ())} frames held back by every fine-tune, their true labels; AP@0.25\n")
    print("| model | mAP (network alone) | " + " | ".join(classes) + " |")
    print("| --- |" + " ---: |" * (len(classes) + 1))
    for tag, report in reports.items():
        aps = [f"{100 * report['classes'][c]['ap']['0.25']:.1f}" for c in classes]
        pipeline, network = (100 * r["map"]["0.25"]["present_classes"] for r in (report, alone[tag]))
        print(f"| {tag} | {pipeline:.1f} ({network:.1f}) | " + " | ".join(aps) + " |")


if __name__ == "__main__":
    sys.exit(main())
