"""Your own room, measured on a synthetic one: world boxes from rough ones, then a fine-tune.

    .venv/bin/python -m bench.own_room --work /tmp/own [--seed 54] [--frames 200] [--loops 2] [--heights H,H]
        [--minutes 15] [--camera realsense-d435 [--camera-scale 2]] [--base real] [--h350 /tmp/h350/test]
        [--skip-finetune | --world-boxes-only] [--rough-from-map]

A room the bundled model did not train on (``a3d-synth --sequence``, ``--world real
--appearance typical``: class-typical materials, where the bundled model saw only materials drawn
whatever the class) stands in for a user's recording, its ``world_boxes.json`` for the boxes a
person would draw; ``--camera`` records it with one of a3d-synth's camera presets (a RealSense's
size, intrinsics and depth model) instead of the NYUv2 crop, ``--camera-scale 2`` at twice its size
(a RealSense's 1280 x 720: docs/running.md "Frames larger than 640 across"); ``--loops 2`` goes
round it twice, hand-held and then as a robot would (lower, on another path, the other way round),
so that the held-back stretch is the room seen again from a robot's height; ``--heights`` sets the
loops' camera heights (``1.0,1.0``: the robot records its own room). Each step runs the commands
a user runs, as subprocesses:

1. the sequence (kept in WORK/seq and reused) and its labels from its world boxes (``a3d-labels``);
2. ``a3d-world-boxes`` from rough boxes: each world box moved 5 to 8 cm along every axis, its
   extents scaled by 0.9 to 1.15 and its yaw turned by 7 degrees (seeded), written as a person's
   rough.csv; the fitted boxes against the room's own: centre distance, size differences and 3D
   IoU (the rough boxes' IoU beside it); with ``--rough-from-map`` also from the rows a3d drafts
   (``a3d-run --map`` with ``--base``, then ``a3d-world-boxes --rough-from``): the rows a person
   keeps, deletes and adds (``map_step``); ``--world-boxes-only`` stops here;
3. ``a3d-finetune`` of ``--base`` (the bundled default pipeline, ``real``) on the labelled
   recording, the last ``--holdout`` (0.4) held back, within ``--minutes``, the load average before
   and after (the machine is shared);
4. ``a3d-run`` + ``a3d-eval`` of the base and the fine-tuned model (which runs with the base's 2D
   detector) on the held-back frames and on ``--h350`` (the README's 350 held-out frames of the
   bundled model's world); per class on the held-back frames, AP and the share of the objects any
   detection finds at all (``per_class``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from a3d.runtime.mapping.rough_boxes import COLUMNS, read_rough_boxes, row_text
from a3d.runtime.mapping.world_boxes import read_world_boxes
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.structures.geometry import iou_3d

BIN = Path(sys.executable).parent


def sh(*words: str | Path) -> float:
    """Run one a3d command (its output to this script's stderr); its wall time in seconds."""
    start = time.perf_counter()
    subprocess.run([str(BIN / str(words[0])), *map(str, words[1:])], check=True, stdout=sys.stderr)
    return time.perf_counter() - start


def load() -> str:
    return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def rough_csv(world_boxes: Path, seed: int = 0) -> str:
    """The world boxes as a person's rough ones (module docstring, step 2)."""
    world = read_world_boxes(world_boxes)
    rng = np.random.default_rng(seed)
    rows = [",".join(COLUMNS)]
    for name, box in zip(world.classes, world.boxes, strict=True):
        centre = box[:3] + rng.choice([-1, 1], 3) * rng.uniform(0.05, 0.08, 3)
        size = box[3:6] * rng.uniform(0.9, 1.15, 3)
        yaw = box[6] + rng.choice([-1, 1]) * math.radians(7)
        rows.append(row_text(name, np.array([*centre, *size, yaw])))
    return "\n".join(rows) + "\n"


def map_step(seq: Path, work: Path, model: str) -> None:
    """Rough boxes from a3d's own object map of the recording (``a3d-run --map``, then
    ``a3d-world-boxes --rough-from``), fitted as they come, against the room's own boxes: the rows a
    person keeps (an object of the room's, same class, 3D IoU >= 0.25, each once, best first),
    deletes (the others) and adds (the objects no row found)."""
    boxes = work / "boxes_map"
    boxes.mkdir(parents=True, exist_ok=True)
    run = sh("a3d-run", seq / "frames", "--model", model, "--output", boxes / "det.jsonl", "--headless",
             "--map", boxes / "map.json")  # fmt: skip
    (boxes / "rough.csv").unlink(missing_ok=True)
    sh("a3d-world-boxes", seq / "frames", "--rough", boxes / "rough.csv", "--rough-from", boxes / "map.json")
    sh("a3d-world-boxes", seq / "frames", "--rough", boxes / "rough.csv")
    truth, fitted = read_world_boxes(seq / "world_boxes.json"), read_world_boxes(boxes / "world_boxes.json")
    rough = read_rough_boxes(boxes / "rough.csv")
    ious = iou_3d(fitted.boxes, truth.boxes, np.eye(3))
    ious[np.array(fitted.classes)[:, None] != np.array(truth.classes)[None, :]] = 0.0
    kept: dict[int, int] = {}
    for row, obj in sorted(np.argwhere(ious >= 0.25).tolist(), key=lambda pair: -ious[pair[0], pair[1]]):
        if row not in kept and obj not in kept.values():
            kept[row] = obj
    frames = len(list((seq / "frames").glob("*.color.*")))
    after = [ious[r, o] for r, o in kept.items()]
    before = [iou_3d(rough.boxes[[r]], truth.boxes[[o]], np.eye(3))[0, 0] for r, o in kept.items()]
    print(f"\n## rough boxes from a3d-run --map ({model}, {run:.0f} s for {frames} frames): "
          f"{len(rough.classes)} rows for the room's {len(truth.classes)} objects\n")  # fmt: skip
    print(f"- kept (the object's class, 3D IoU >= 0.25 after the fit): {len(kept)}, median 3D IoU "
          f"{np.median(after) if kept else 0:.2f} (the rows as a3d-run mapped them: "
          f"{np.median(before) if kept else 0:.2f})")  # fmt: skip
    wrong = [fitted.classes[r] for r in range(len(fitted.classes)) if r not in kept]
    missed = [truth.classes[o] for o in range(len(truth.classes)) if o not in kept.values()]
    print(f"- to delete: {len(wrong)} ({', '.join(sorted(wrong))})")
    print(f"- to add: {len(missed)} ({', '.join(sorted(missed))})")


def world_boxes_step(seq: Path, work: Path) -> None:
    boxes = work / "boxes"
    boxes.mkdir(parents=True, exist_ok=True)
    (boxes / "rough.csv").write_text(rough_csv(seq / "world_boxes.json"))
    seconds = sh(
        "a3d-world-boxes", seq / "frames", "--rough", boxes / "rough.csv", "--save", boxes / "fitted.rrd"
    )
    truth, fitted = read_world_boxes(seq / "world_boxes.json"), read_world_boxes(boxes / "world_boxes.json")
    rough = read_rough_boxes(boxes / "rough.csv").boxes
    centres = np.linalg.norm(fitted.boxes[:, :3] - truth.boxes[:, :3], axis=1)
    sizes = np.abs(fitted.boxes[:, 3:6] - truth.boxes[:, 3:6])
    ious = [np.diag(iou_3d(truth.boxes, boxes, np.eye(3))) for boxes in (rough, fitted.boxes)]
    print(f"\n## a3d-world-boxes ({seconds:.0f} s, {load()})\n")
    print("| object | centre off (m) | l, w, h off (m) | 3D IoU: rough -> fitted |")
    print("| --- | --- | --- | --- |")
    for name, centre, size, before, after in zip(truth.classes, centres, sizes, *ious, strict=True):
        sized = ", ".join(f"{v:.3f}" for v in size)
        print(f"| {name} | {centre:.3f} | {sized} | {before:.2f} -> {after:.2f} |")
    median = ", ".join(f"{v:.3f}" for v in np.median(sizes, axis=0))
    before, after = (np.median(v) for v in ious)
    print(f"| **median** | {np.median(centres):.3f} | {median} | {before:.2f} -> {after:.2f} |")
    close = ", ".join(f"{(centres < bar).sum()} within {100 * bar:.0f} cm" for bar in (0.02, 0.05, 0.1))
    print(f"\n{len(centres)} objects: {close}")


def scores(model: str | Path, frames: Path, out: Path, *run_args: str) -> dict:
    """a3d-eval's report (its eval.json) of the model's a3d-run on the frames (``run_args``: more
    of a3d-run's flags, e.g. ``--detector none``)."""
    sh("a3d-run", frames, "--model", model, "--output", out.with_suffix(".jsonl"), "--headless", *run_args)
    sh("a3d-eval", frames, "--detections", out.with_suffix(".jsonl"), "--out", out)
    return json.loads((out / "eval.json").read_text())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--seed", type=int, default=54, help="the room (54: a living room of 12 classes)")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--loops", type=int, default=1, choices=(1, 2), help="loops round the room (a3d-synth)")
    p.add_argument("--heights", help="the loops' camera heights in metres, H or H,H (a3d-synth)")
    p.add_argument("--camera", help="a3d-synth's camera preset that records the room (default: NYUv2 crop)")
    p.add_argument("--camera-scale", help="the preset's frame size times this (a3d-synth --camera-scale)")
    p.add_argument("--holdout", type=float, default=0.4)
    p.add_argument("--minutes", type=float, default=15.0)
    p.add_argument("--base", default="real", help="the bundled model to fine-tune and compare with")
    p.add_argument("--h350", type=Path, help="the 350 held-out frames of the bundled model's world")
    p.add_argument("--skip-finetune", action="store_true", help="score the WORK/ft.onnx made before")
    p.add_argument("--world-boxes-only", action="store_true", help="steps 1 and 2 alone: the world boxes")
    p.add_argument("--rough-from-map", action="store_true", help="step 2 also from a3d-run --map's map")
    args = p.parse_args(argv)
    seq, labelled, model = args.work / "seq", args.work / "labelled", args.work / "ft.onnx"
    if not (seq / "world_boxes.json").is_file():
        camera = ["--camera-mix", args.camera] if args.camera else []
        camera += ["--camera-scale", args.camera_scale] if args.camera_scale else []
        camera += ["--heights", args.heights] if args.heights else []
        sh("a3d-synth", seq, "--sequence", args.frames, "--seed", args.seed, "--world", "real",
           "--appearance", "typical", "--workers", "2", "--loops", args.loops, *camera)  # fmt: skip
    if not labelled.is_dir():
        sh("a3d-labels", seq / "world_boxes.json", seq / "frames", "--out", labelled)
    world_boxes_step(seq, args.work)
    if args.rough_from_map:
        map_step(seq, args.work, args.base)
    if args.world_boxes_only:
        return 0
    if not args.skip_finetune:
        before = load()
        seconds = sh(
            "a3d-finetune", labelled, "--out", model, "--minutes", args.minutes, "--holdout", args.holdout,
            "--base", args.base,
        )
        print(f"\n## a3d-finetune: {seconds / 60:.1f} minutes; before: {before}; after: {load()}")
    held = args.work / "ft.finetune" / "holdout"
    print(f"\n| frames | bundled `{args.base}` | fine-tuned |\n| --- | --- | --- |")
    sets = [("held-back frames of the room", held)] + ([("--h350", args.h350)] if args.h350 else [])
    reports = {}
    for what, frames in sets:
        reports[frames] = [scores(m, frames, args.work / f"eval_{k}_{frames.name}")
                           for k, m in (("base", args.base), ("ft", model))]  # fmt: skip
        maps = [report["map"]["0.25"] for report in reports[frames]]
        (a, a_present), (b, b_present) = ((m["all_classes"], m["present_classes"]) for m in maps)
        print(f"| {what}: mAP@0.25 (their classes / 19) | {100 * a_present:.1f} / {100 * a:.1f} "
              f"| {100 * b_present:.1f} / {100 * b:.1f} |")  # fmt: skip
    card = DetectorModel.load(model, threads=1).metadata.provenance["finetune"].get("heldout_map25_pipeline")
    if card:  # a3d-finetune's own scoring of the same frames, which the first row should repeat
        print(f"\na3d-finetune's card, the pipeline with {card['detector']} on the held-back frames: "
              f"{100 * card['before_present']:.1f} -> {100 * card['after_present']:.1f}")  # fmt: skip
    print(per_class(*reports[held]))
    return 0


def per_class(before: dict, after: dict) -> str:
    """The held-back frames' classes (a3d-eval's reports, base and fine-tuned): AP@0.25 before and
    after, and the share of the class's objects that any detection finds at 3D IoU >= 0.25 (where
    its precision-recall curve ends): no ranking of the detections lifts a class's AP above it."""
    rows = ["\n| class | objects | AP@0.25 before -> after | found at all, before -> after |",
            "| --- | ---: | ---: | ---: |"]
    for name in before["present_classes"]:
        a, b = before["classes"][name], after["classes"][name]
        reach = [max(c["curve"]["0.25"]["recall"]) for c in (a, b)]
        rows.append(f"| {name} | {a['num_gt']} | {100 * a['ap']['0.25']:.1f} -> {100 * b['ap']['0.25']:.1f} "
                    f"| {reach[0]:.2f} -> {reach[1]:.2f} |")  # fmt: skip
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
