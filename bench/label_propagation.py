"""Labels drawn once against a3d-synth's own per-frame ground truth, on a posed synthetic sequence.

    .venv/bin/python -m bench.label_propagation --frames 200 --seed 11 --work /tmp/a3d_labels [--size HxW]

Renders one room seen from ``--frames`` poses (``a3d-synth --sequence``, kept in WORK/sequence and
reused), runs ``a3d-labels`` on its world_boxes.json and frames (into WORK/labelled) and compares
every frame's propagated ground truth with the one a3d-synth rendered:

* boxes: for every object both annotate, the largest difference of the 3D box (metres / radians,
  up to the box's symmetry) and of the amodal 2D box (pixels); the bar is 1e-6;
* visibility decisions: over every object-frame whose box is in view (projects into the image),
  whether both give the object an entry or both give none; the bar is 98 %;
* beside it, the IoU of the visible 2D boxes (seen pixels against a3d-synth's visible pixels).

``compare`` is what tests/test_labels.py runs on a small sequence.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3d.runtime.cli import labels as labels_cli
from a3d.runtime.mapping.world import box_differences, boxes_to_camera, same_boxes
from a3d.runtime.mapping.world_boxes import WORLD_BOXES_FILE, read_world_boxes
from a3d.runtime.sources.folder import LABELS_FILE, list_frames, read_ground_truth, read_meta
from a3d.runtime.structures.geometry import iou_2d
from a3d.synth.cli import main as synth_main

BOX_BAR = 1e-6
DECISION_BAR = 0.98


@dataclass(frozen=True)
class Comparison:
    """What ``compare`` found: frames; object-frames in view and how many decisions agree; the
    object-frames both annotate; the largest 3D and amodal 2D box differences among those; the
    mean IoU of their visible 2D boxes; the disagreements as (frame, class, synth's, ours)."""

    frames: int
    in_view: int
    agree: int
    both: int
    box3d_max: float
    amodal_max: float
    visible_iou: float
    disagreements: list[tuple[str, str, bool, bool]]

    @property
    def agreement(self) -> float:
        return self.agree / max(self.in_view, 1)

    def passed(self) -> bool:
        return self.box3d_max <= BOX_BAR and self.amodal_max <= BOX_BAR and self.agreement >= DECISION_BAR


def compare(sequence: Path, labelled: Path) -> Comparison:
    """Compare a3d-labels' output (``labelled``) with the sequence's own ground truth (``sequence``:
    an a3d-synth --sequence folder with frames/ and world_boxes.json)."""
    world = read_world_boxes(sequence / WORLD_BOXES_FILE)
    records = {r["frame"]: r for r in map(json.loads, (labelled / LABELS_FILE).read_text().splitlines())}
    ours_refs = {ref.name: ref for ref in list_frames(labelled)}
    in_view = agree = both = 0
    box3d_max = amodal_max = 0.0
    ious: list[float] = []
    disagreements = []
    for ref in list_frames(sequence / "frames"):
        synth, ours = read_ground_truth(ref), read_ground_truth(ours_refs[ref.name])
        meta = read_meta(ref)
        in_camera = boxes_to_camera(world.boxes, meta.pose, meta.R_tilt)
        rows = same_boxes(synth.boxes3d, in_camera)
        assert (rows >= 0).all(), f"{ref.name}: a ground-truth box that is no world box"
        synth_ids = [int(world.ids[k]) for k in rows]
        objects = records[ref.name]["objects"]
        ours_ids = [o["id"] for o in objects if o["labelled"]]  # in the order of ours' rows
        for k in {o["id"] for o in objects} | set(synth_ids):
            a, b = k in synth_ids, k in ours_ids
            in_view += 1
            agree += a == b
            if a != b:
                disagreements.append((ref.name, world.classes[list(world.ids).index(k)], a, b))
        for i, k in enumerate(synth_ids):
            if k not in ours_ids:
                continue
            j = ours_ids.index(k)
            both += 1
            box3d_max = max(box3d_max, float(box_differences(synth.boxes3d[i], ours.boxes3d[j])[0]))
            amodal_max = max(
                amodal_max, float(np.abs(synth.boxes2d_amodal[i] - ours.boxes2d_amodal[j]).max())
            )
            ious.append(
                float(iou_2d(synth.boxes2d_visible[i : i + 1], ours.boxes2d_visible[j : j + 1])[0, 0])
            )
    iou = float(np.mean(ious)) if ious else 0.0
    return Comparison(len(records), in_view, agree, both, box3d_max, amodal_max, iou, disagreements)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=200, help="views of the room")
    p.add_argument("--seed", type=int, default=11, help="the room's seed")
    p.add_argument("--size", default=None, metavar="HxW", help="image size (default: a3d-synth's, 427x561)")
    p.add_argument("--workers", type=int, default=1, help="a3d-synth's worker processes")
    p.add_argument("--work", type=Path, default=Path("/tmp/a3d_labels"), help="working folder")
    args = p.parse_args(argv)
    sequence, labelled = args.work / "sequence", args.work / "labelled"
    if not (sequence / WORLD_BOXES_FILE).exists():
        size = [] if args.size is None else ["--size", args.size]
        synth = [str(sequence), "--sequence", str(args.frames), "--seed", str(args.seed), *size]
        assert synth_main([*synth, "--workers", str(args.workers)]) == 0
    start = time.perf_counter()
    code = labels_cli.main(
        [str(sequence / WORLD_BOXES_FILE), str(sequence / "frames"), "--out", str(labelled)]
    )
    seconds = time.perf_counter() - start
    result = compare(sequence, labelled)
    r = result
    print(
        f"sequence: {sequence} ({r.frames} frames, seed {args.seed}); a3d-labels exit {code}, {seconds:.1f} s"
    )
    print(f"object-frames in view: {r.in_view}; decisions agree: {r.agree} ({100 * r.agreement:.2f} %)")
    print(
        f"object-frames both annotate: {r.both}; largest difference: 3D box {r.box3d_max:.2e}, amodal 2D box"
    )
    print(f"  {r.amodal_max:.2e} px (bar {BOX_BAR:g}); visible 2D boxes: mean IoU {r.visible_iou:.3f}")
    for name, cls, synth_has, ours_has in r.disagreements:
        print(f"  {name} {cls}: annotated by a3d-synth {synth_has}, by a3d-labels {ours_has}")
    print("PASS" if result.passed() else "FAIL")
    return 0 if result.passed() and code == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
