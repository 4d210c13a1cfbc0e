"""How the depth support's two constants were chosen (a3d.runtime.postprocess.depth_support).

    .venv/bin/python -m bench.depth_support --synthetic /tmp/v350/test --weights 0,1,1.5,2,3,4
    .venv/bin/python -m bench.depth_support --real REAL_FRAMES --references 0.35,0.5,0.6 --out DIR

``--synthetic FOLDER`` (a3d-synth frames with ground truth; the weight was chosen on 350 frames of
seed 2031, ``a3d-synth /tmp/v350 --frames 350 --seed 2031 --world real --split test=1``, which no
other benchmark uses): the bundled pipeline ``real``'s mAP@0.25 for each ``SUPPORT_WEIGHT`` (0:
no support). The reference moves every score by the same amount in log-odds, so it changes no
ranking and no AP; ``--real FOLDER`` (the real frames of bench.real_frames) gives, for each
``SUPPORT_REFERENCE``, what a threshold of 0.5 keeps there: objects found and the share of the
detections that are right (bench.real_frames's counts, its JSON under DIR/REF).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from a3d.runtime import Detector
from a3d.runtime.evaluation.metric import EvalConfig, EvalResult, evaluate
from a3d.runtime.evaluation.truth import load_truth
from a3d.runtime.postprocess import depth_support
from a3d.runtime.sources.folder import FolderSource
from bench import real_frames


def real_result(folder: Path) -> EvalResult:
    """The bundled pipeline ``real`` on a3d-synth frames with ground truth, scored (a3d-eval's metric)."""
    detector = Detector.load("real", threads=2)
    truth, _ = load_truth(folder)
    outcomes = detector.detect_frames(FolderSource(folder), score_threshold=0)
    found = {o.detections.frame: o.detections for o in outcomes}
    return evaluate(truth, found, EvalConfig())


def synthetic_map(folder: Path, weight: float) -> float:
    """``real``'s mAP@0.25 over the frames' classes with ``SUPPORT_WEIGHT`` = ``weight``."""
    depth_support.SUPPORT_WEIGHT = weight
    return real_result(folder).map_present(0.25)


def real_frames_result(folder: Path, out: Path) -> dict:
    """bench.real_frames's JSON for ``real`` on the real frames (its files under ``out``, its tables
    to stderr)."""
    with contextlib.redirect_stdout(sys.stderr):
        code = real_frames.main([str(folder), "--model", "real", "--out", str(out)])
    if code:
        raise SystemExit(code)
    return json.loads((out / "real_frames.json").read_text())


def real_counts(folder: Path, reference: float, out: Path) -> dict:
    """bench.real_frames's totals for ``real`` with ``SUPPORT_REFERENCE`` = ``reference``."""
    depth_support.SUPPORT_REFERENCE = reference
    return real_frames_result(folder, out)["total"]


def floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--synthetic", type=Path, help="a3d-synth frames with ground truth")
    p.add_argument("--weights", type=floats, default=[0.0, 1.0, 1.5, 2.0, 3.0, 4.0])
    p.add_argument("--real", type=Path, help="the real frames of bench.real_frames")
    p.add_argument("--references", type=floats, default=[0.35, 0.5, 0.6])
    p.add_argument("--out", type=Path, default=Path("/tmp/bench_depth_support"))
    args = p.parse_args(argv)
    if args.synthetic is None and args.real is None:
        p.error("give --synthetic FOLDER, --real FOLDER or both")
    shipped = depth_support.SUPPORT_WEIGHT
    if args.synthetic is not None:
        print(f"| SUPPORT_WEIGHT | `real`, mAP@0.25 on {args.synthetic} |\n| ---: | ---: |")
        for weight in args.weights:
            print(f"| {weight:g} | {100 * synthetic_map(args.synthetic, weight):.2f} |", flush=True)
        depth_support.SUPPORT_WEIGHT = shipped
    if args.real is not None:
        rows = []
        for reference in args.references:
            total = real_counts(args.real, reference, args.out / f"{reference:g}")
            rows.append(f"| {reference:g} | {total['found']} of {total['objects']} | {total['right']} / "
                        f"{total['detections']} ({100 * total['precision']:.0f} %) |")  # fmt: skip
        print("\n| SUPPORT_REFERENCE | found at >= 0.5 | right / detections |\n| ---: | ---: | ---: |")
        print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
