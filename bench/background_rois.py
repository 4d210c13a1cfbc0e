"""How many training RoIs a set offers as background, at two lower IoU bounds for background.

    .venv/bin/python -m bench.background_rois out/real40/train [--config cpu-small] [--low 0.1 0.0]

Fast R-CNN's sampling (``data.bg_iou_low``, 0.1 by default) takes as background only proposals
that overlap some labelled object by 2D IoU >= 0.1: a proposal on clutter away from every
labelled object is never trained on, and a frame without labelled objects (``--empty-share``)
has no RoI at all and is skipped. With a lower bound of 0 every proposal that is no foreground
is background, which is what the cluttered world is for. This builds the RoI database of FOLDER
(one proposal cache) at each bound and prints, per bound, the frames kept, the background RoIs
per kept frame and the foreground RoIs (unchanged by the bound), as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from a3d.train.config import apply_overrides, load_config
from a3d.train.roidb import build_roidb


def background_counts(folder: Path, config, lows: list[float], cache: Path) -> dict[str, dict]:
    """Per lower bound: frames kept and skipped, background and foreground RoIs."""
    out = {}
    for low in lows:
        db = build_roidb(folder, apply_overrides(config, [f"data.bg_iou_low={low}"]), cache)
        bg = sum(int((r.labels == 0).sum()) for r in db.records)
        out[str(low)] = {
            "frames_kept": len(db.records),
            "frames_skipped": len(db.skipped),
            "background_rois": bg,
            "background_per_frame": bg / max(len(db.records), 1),
            "foreground_rois": sum(r.num_fg for r in db.records),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--config", default="cpu-small")
    parser.add_argument(
        "--low", type=float, nargs="+", default=[0.1, 0.0], help="background IoU lower bounds"
    )
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    config = load_config(args.config, args.sets)
    with tempfile.TemporaryDirectory() as cache:
        report = background_counts(args.folder, config, args.low, Path(cache))
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
