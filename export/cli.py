"""a3d-export: a trained checkpoint -> one self-contained model.onnx for a3d-run.

    a3d-export CHECKPOINT -o model.onnx [--verify-frames FOLDER] [--svd RANK]
               [--int8 --calib FOLDER [--calib-frames N]] [--opset 18] [--score-threshold S]
               [--score-calibration FOLDER]

The checkpoint is loaded, exported, verified against torch, optionally quantised and
calibrated, and written with its metadata (the steps: a3d.export.build, imported once the flags
parse, so --help and --version need neither torch nor onnx); then the a3d-run command that uses
the model is printed.

Exit codes: 0 ok, 1 verification failed, 2 usage or bad input (one line naming the file).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from a3d.export.base import MIN_OPSET, PROG, VERIFY_FRAMES, ExportError
from a3d.runtime.cli.common import EXIT_FAILED, command
from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.extras import Needs

NEEDS = Needs("train", ("torch", "onnx", "onnxscript"))  # checked after parsing: --help works without
CALIB_FRAMES = 16


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0], needs=NEEDS)
    p.add_argument("checkpoint", type=Path, help="a3d-train checkpoint (RUN_DIR/checkpoint.pt)")
    p.add_argument("-o", "--output", type=Path, required=True, help="the model file to write (model.onnx)")
    p.add_argument(
        "--verify-frames",
        type=Path,
        metavar="FOLDER",
        help=f"verify on the first {VERIFY_FRAMES} frames of FOLDER (default: a synthetic image)",
    )
    p.add_argument("--svd", type=int, metavar="RANK", help="truncated SVD of fc6 and fc7 at this rank")
    p.add_argument("--int8", action="store_true", help="static int8 quantisation (QDQ, per channel)")
    p.add_argument("--calib", type=Path, metavar="FOLDER", help="frame folder for the int8 calibration")
    p.add_argument(
        "--calib-frames",
        type=int,
        default=CALIB_FRAMES,
        metavar="N",
        help="calibration frames",
    )
    p.add_argument("--opset", type=int, default=MIN_OPSET, help=f"ONNX opset >= {MIN_OPSET}")
    p.add_argument(
        "--score-threshold",
        type=float,
        metavar="S",
        help="detections below S are dropped at run time (default: the training config's)",
    )
    p.add_argument(
        "--score-calibration",
        type=Path,
        metavar="FOLDER",
        help="fit the per-class score calibration on FOLDER's annotated frames (held out from "
        "training, same world): a score then says how likely a detection is right",
    )
    p.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads for verification")
    return p


@command(PROG, errors=(ExportError, ValueError, OSError))
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.int8 != (args.calib is not None):
        parser.error("--int8 and --calib FOLDER go together")
    if args.calib_frames < 1 or args.threads < 1:
        parser.error("--calib-frames and --threads must be positive")
    if args.score_threshold is not None and not 0.0 <= args.score_threshold <= 1.0:
        parser.error(f"--score-threshold must be in [0, 1], got {args.score_threshold}")
    if args.score_calibration is not None and not args.score_calibration.is_dir():
        raise ExportError(f"--score-calibration {args.score_calibration}: no such folder")
    from a3d.export.build import VerificationError, export  # torch and onnx (NEEDS)

    try:
        path = export(args)
    except VerificationError as e:
        print(f"{PROG}: verification failed: {e}", file=sys.stderr)
        return EXIT_FAILED
    print(f"{PROG}: wrote {path}; run it with (add --save run.rrd to record the view, or drop --headless "
          "to watch it live on a display):", file=sys.stderr)  # fmt: skip
    print(f"a3d-run FRAMES --model {shlex.quote(str(path.resolve()))} --output detections.jsonl --headless")
    return 0


if __name__ == "__main__":
    sys.exit(main())
