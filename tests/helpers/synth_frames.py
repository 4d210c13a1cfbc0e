"""Small annotated a3d.synth frames for tests that need realistic RGB-D input, not a fixed layout."""

from __future__ import annotations

from pathlib import Path

from a3d.synth.cli import generate, scaled_intrinsics
from a3d.synth.scene import SceneConfig


def write_synth_frames(folder: Path, count: int, seed: int = 0, size: tuple[int, int] = (96, 128)) -> Path:
    """``count`` a3d.synth frames of ``size`` (H, W) written into ``folder`` (as a3d-synth writes
    its training split: intrinsics.json, colour, depth, meta, ground truth, instances)."""
    config = SceneConfig(image_size=size, intrinsics=scaled_intrinsics(size))
    generate(folder, count, seed, test_share=0.0, workers=1, config=config, progress=False)
    return folder / "train"
