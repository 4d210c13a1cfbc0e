"""``a3d-nyuv2 RELEASE OUT``: convert the authors' NYUv2 release into a3d frame folders.

    a3d-nyuv2 dataset/NYUV2 data/nyuv2                       # OUT/train (795), OUT/test (654)
    a3d-nyuv2 dataset/NYUV2 data/nyuv2 --mcg matlab/NYUV2/Segs   # + NAME.proposals.npz from MCG
    a3d-nyuv2 dataset/NYUV2 data/nyuv2 --limit 20             # the first 20 images of each split

RELEASE is the unzipped ``NYUV2_3D_dataset.zip`` (layout: ``a3d.train.data.nyuv2``). Each image
``i`` of ``trainval.txt`` / ``test.txt`` becomes frame ``%04d`` in OUT/train or OUT/test: the
release's JPEG copied unchanged, its raw depth (or, with ``--depth filled``, its hole-filled
depth) as a millimetre PNG, ``R_tilt`` in ``NAME.meta.json``, the 19-class ground truth in
``NAME.gt.json`` (possibly empty: the authors skip such images in training), and the NYUv2
standard-crop intrinsics in ``intrinsics.json``. With ``--mcg SEGS`` the authors' MCG candidates
``SEGS/NYU%04d/candidates.mat`` become ``NAME.proposals.npz``, filtered as the authors do (box
area >= 200 px, first 2000). Bad input is one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.errors import InputError
from a3d.runtime.extras import Needs
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.sources.proposals_file import write_precomputed_proposals
from a3d.runtime.structures.geometry import NYU_CROP_INTRINSICS
from a3d.train.data.mcg import AUTHORS_MAX_PROPOSALS, AUTHORS_MIN_BOX_AREA, read_mcg_candidates
from a3d.train.data.nyuv2 import SPLIT_SIZES, read_image, read_split

PROG = "a3d-nyuv2"
NEEDS = Needs("train", ("scipy",))  # the release's .mat files; checked after parsing


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(PROG, "Convert the authors' NYUv2 release to a3d frames.", needs=NEEDS)
    parser.add_argument(
        "release", type=Path, help="unzipped NYUV2_3D_dataset folder (annotations/, color/, ...)"
    )
    parser.add_argument("out", type=Path, help="output folder: OUT/train and OUT/test are written")
    parser.add_argument(
        "--depth",
        choices=("raw", "filled"),
        default="raw",
        help="raw sensor depth with holes (a3d fills holes itself) or the release's filled depth",
    )
    parser.add_argument("--mcg", type=Path, metavar="SEGS", help="folder of NYU%%04d/candidates.mat (MCG)")
    parser.add_argument(
        "--limit", type=int, metavar="N", help="convert only the first N images of each split"
    )
    return parser


def convert(release: Path, out: Path, depth: str, mcg: Path | None, limit: int | None) -> dict[str, dict]:
    """Convert both splits; returns per split the number of frames, objects and empty frames."""
    splits = {name: read_split(release, name) for name in ("train", "test")}
    shared = sorted(set(splits["train"]) & set(splits["test"]))
    if shared:
        raise InputError(f"{release}: image {shared[0]} is in both trainval.txt and test.txt")
    for name, indices in splits.items():
        if len(indices) != SPLIT_SIZES[name]:
            print(f"{PROG}: note: {name} split has {len(indices)} images (standard: {SPLIT_SIZES[name]})")
    jobs = [(name, index) for name, indices in splits.items() for index in indices[:limit]]
    for name in splits:
        write_intrinsics(out / name, NYU_CROP_INTRINSICS)
    summary = {name: {"frames": 0, "objects": 0, "without_objects": 0} for name in splits}
    for name, index in tqdm(jobs, desc=PROG, unit="image", dynamic_ncols=True):
        image = read_image(release, index)
        frame = f"{index:04d}"
        proposals = None
        if mcg is not None:
            candidates = mcg / f"NYU{index:04d}" / "candidates.mat"
            proposals = read_mcg_candidates(
                candidates, min_box_area=AUTHORS_MIN_BOX_AREA, max_proposals=AUTHORS_MAX_PROPOSALS
            )
            if proposals.image_size != image.image_size:
                (h, w), (ih, iw) = proposals.image_size, image.image_size
                raise InputError(f"{candidates}: superpixels are {h}x{w} but the image is {ih}x{iw}")
        depth_m = image.depth_raw if depth == "raw" else image.depth_filled
        write_frame(out / name, frame, image.color, depth_m, R_tilt=image.R_tilt, gt=image.gt)
        if proposals is not None:
            write_precomputed_proposals(out / name / f"{frame}.proposals.npz", proposals)
        summary[name]["frames"] += 1
        summary[name]["objects"] += len(image.gt)
        summary[name]["without_objects"] += len(image.gt) == 0
    return summary


@command(PROG)
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.limit is not None and args.limit < 1:
        parser.error("--limit must be positive")
    summary = convert(args.release, args.out, args.depth, args.mcg, args.limit)
    for name, counts in summary.items():
        print(
            f"{args.out / name}: {counts['frames']} frames, {counts['objects']} objects, "
            f"{counts['without_objects']} frames without objects"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
