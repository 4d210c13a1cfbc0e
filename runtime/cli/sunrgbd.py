"""a3d-sunrgbd SRC OUT: convert SUN RGB-D, in either common layout, into a3d frame folders.

    a3d-sunrgbd SUNRGBD data/sunrgbd                         # the release (or any folder of it)
    a3d-sunrgbd sunrgbd_trainval data/sunrgbd --classes sun10  # VoteNet / mmdetection3d's layout
    a3d-sunrgbd SUNRGBD data/sunrgbd --split SUNRGBDtoolbox/traintestSUNRGBD/allsplit.mat

SRC is read by a3d.runtime.sources.sunrgbd (layouts, conventions and class mapping are described
there and in docs/sources.md). Every frame becomes one a3d frame (README "Frame format") in
OUT/train or OUT/val, the data set's official split: for VoteNet's layout its
train_data_idx.txt / val_data_idx.txt, for the release the toolbox's allsplit.mat (alltrain ->
train, alltest -> val; given with --split or found as SUNRGBDtoolbox/traintestSUNRGBD/allsplit.mat
in SRC or a folder above it). Frames the split does not list go to OUT/other; without a split
file everything goes to OUT/all, and a note says so. A frame is its colour JPEG copied unchanged,
its depth as a millimetre PNG (the release's depth is whole millimetres; a VoteNet point cloud's
is rounded to them), NAME.meta.json with its own intrinsics (four sensors) and R_tilt, and
NAME.gt.json with the objects of --classes (nyu19: the paper's 19 classes; sun10: the SUN RGB-D
benchmark's 10). A frame that cannot be read is named on stderr in one line and the rest go on;
exit 1 if any failed, 2 if SRC is unusable before any frame.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from tqdm import tqdm

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.io.image_io import read_bytes
from a3d.runtime.pipeline import frame_problem
from a3d.runtime.sources.folder import write_frame
from a3d.runtime.sources.sunrgbd import DEPTH_FOLDERS, ReleaseSource, SunOptions, open_sunrgbd
from a3d.runtime.sources.sunrgbd_conventions import CLASS_SETS

PROG = "a3d-sunrgbd"


def build_parser() -> argparse.ArgumentParser:
    p = command_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("src", type=Path, help="SUN RGB-D: release frame folder(s), or VoteNet's sunrgbd_trainval")
    p.add_argument("out", type=Path, help="output: OUT/train and OUT/val (OUT/all without a split)")
    p.add_argument("--classes", choices=list(CLASS_SETS), default="nyu19", help="ground-truth classes")
    p.add_argument(
        "--depth", choices=list(DEPTH_FOLDERS), default="raw", help="release: raw depth/ or filled depth_bfx/"
    )
    p.add_argument("--split", type=Path, metavar="ALLSPLIT.MAT", help="release: the toolbox's split file")
    p.add_argument("--limit", type=int, metavar="N", help="convert only the first N frames")
    return p


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.limit is not None and args.limit < 1:
        parser.error("--limit must be at least 1")
    source = open_sunrgbd(args.src, SunOptions(depth=args.depth, classes=args.classes))
    if isinstance(source, ReleaseSource):
        splits = source.splits(args.split)
    else:
        if args.split is not None:
            parser.error("--split is for the release layout (VoteNet's has train/val_data_idx.txt)")
        splits = source.splits()
    if splits is None:
        print(f"{PROG}: note: {args.src}: no split file found; every frame goes to {args.out / 'all'}")
    failures = list(source.incomplete)
    for problem in failures:
        print(f"{PROG}: {problem}", file=sys.stderr)
    frames: Counter[str] = Counter()
    objects: Counter[str] = Counter()
    loaders = list(source)[: args.limit]
    for loader in tqdm(loaders, desc=PROG, unit="frame", file=sys.stderr, disable=None):
        split = "all" if splits is None else splits.get(loader.name, "other")
        try:
            frame = loader.load()
            color = read_bytes(Path(frame.color_file or loader.origin))
            write_frame(
                args.out / split,
                loader.name,
                color,
                frame.depth,
                R_tilt=frame.R_tilt,
                intrinsics_override=frame.intrinsics,
                gt=frame.truth if frame.R_tilt is not None else None,
            )
        except ValueError as e:  # InputError included: one line per bad frame
            failures.append(frame_problem(loader, e))
            tqdm.write(f"{PROG}: {failures[-1]}", file=sys.stderr)
            continue
        frames[split] += 1
        objects[split] += 0 if frame.truth is None else len(frame.truth)
    for split in sorted(frames):
        print(f"{args.out / split}: {frames[split]} frames, {objects[split]} objects ({args.classes})")
    if failures:
        print(f"{PROG}: {len(failures)} frame(s) failed", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
