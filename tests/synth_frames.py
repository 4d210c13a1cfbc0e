"""A few small a3d-synth frames as an a3d frame folder: the reference the tests of the other frame
sources (bags, a RealSense camera) compare their frames and detections with."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.io.detections_io import parse_line
from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.synth.cli import scaled_intrinsics
from a3d.synth.scene import SceneConfig, generate_frame

SIZE = (120, 160)
K = scaled_intrinsics(SIZE)
CONFIG = replace(SceneConfig(), image_size=SIZE, intrinsics=K)
SEEDS = (0, 1, 2)


def write_synth_folder(root: Path) -> Path:
    """The frames ``f0``, ``f1``, ``f2`` without R_tilt (bags and cameras have none either)."""
    write_intrinsics(root, K)
    for seed in SEEDS:
        frame = generate_frame(seed, CONFIG)
        write_frame(root, f"f{seed}", frame.color, frame.depth)
    return root


def folder_frames(folder: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """(colour BGR, depth uint16 mm) exactly as the folder stores them."""
    return [
        (
            cv2.imread(str(folder / f"f{s}.color.png"), cv2.IMREAD_COLOR),
            cv2.imread(str(folder / f"f{s}.depth.png"), cv2.IMREAD_UNCHANGED),
        )
        for s in SEEDS
    ]


def assert_same_detections(got: Path, want: Path, count: int = len(SEEDS)) -> None:
    """Two detections files hold the same detections, line by line, to 1e-6 (names aside)."""
    a = [parse_line(text, f"{got}:{i}") for i, text in enumerate(got.read_text().splitlines(), 1)]
    b = [parse_line(text, f"{want}:{i}") for i, text in enumerate(want.read_text().splitlines(), 1)]
    assert len(a) == len(b) == count
    for x, y in zip(a, b, strict=True):
        assert list(x.class_ids) == list(y.class_ids) and len(x.class_ids) > 0
        for field in ("R_tilt", "scores", "boxes2d", "boxes3d"):
            np.testing.assert_allclose(getattr(x, field), getattr(y, field), rtol=0, atol=1e-6)
