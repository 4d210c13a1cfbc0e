"""A frozen colour trunk's conv5_3 features, computed once per training frame and cached on disk.

Why: the recipe for learning from synthetic images (Hinterstoisser et al., ECCV workshops 2018) is
a feature extractor pretrained on real images, frozen, with the rest trained on the synthetic
data. A frozen full-width VGG16 gives the same features for a frame in every epoch, and on two
CPU cores it costs more than the rest of a training step together; so its output is computed
once per frame and flip (``solver.freeze_color`` = all 13 convolutions, ``data.augment`` off) and
a CPU hour trains the depth trunk and the head alone.

The features are stored as float16 (float32 where a value would overflow it),
``NAME-KEY.scale<S>.color-<DIGEST>.npz`` beside the frame's
resized-frame cache (a3d.train.scaled_frames; the same NAME-KEY, so a changed frame misses),
``DIGEST`` naming the trunk's weights: another trunk never reads them. The flipped frame's
features are the trunk run on the flipped image (a trunk's output does not commute with a flip).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from a3d.runtime.io.atomic import atomic_write
from a3d.runtime.network.preprocess import color_input
from a3d.train.model.vgg import VGG16Trunk
from a3d.train.roidb import UNREADABLE_CACHE, FrameRois
from a3d.train.scaled_frames import load_scaled_frame, scaled_frame_path

FLIPS = ("plain", "flipped")
HALF_MAX = 6e4  # float16's largest value is 65504


def trunk_digest(trunk: VGG16Trunk) -> str:
    """12 hex digits of a SHA-1 over the trunk's tensors (names, shapes and float32 bytes)."""
    digest = hashlib.sha1()
    for name, value in sorted(trunk.state_dict().items()):
        digest.update(name.encode())
        digest.update(str(tuple(value.shape)).encode())
        digest.update(value.detach().to("cpu", torch.float32).contiguous().numpy().tobytes())
    return digest.hexdigest()[:12]


def features_path(record: FrameRois, scale: float, digest: str) -> Path:
    """``NAME-KEY.scale0.5.npz`` -> ``NAME-KEY.scale0.5.color-DIGEST.npz``."""
    frame = scaled_frame_path(record, scale)
    return frame.with_name(f"{frame.stem}.color-{digest}.npz")


def load_color_features(record: FrameRois, scale: float, digest: str, flip: bool) -> np.ndarray:
    """(C, h, w) float32 features of the record's frame (or its mirror image) from the cache."""
    path = features_path(record, scale, digest)
    try:
        with np.load(path) as z:
            return z[FLIPS[int(flip)]].astype(np.float32)
    except UNREADABLE_CACHE:
        raise FileNotFoundError(f"{path}: colour features missing or unreadable; cache_color_features "
                                "computes them before training") from None  # fmt: skip


def _stored(features: np.ndarray) -> np.ndarray:
    """float16 (half the disk) where every value fits it, else float32: never an overflow to inf."""
    if not np.isfinite(features).all():
        raise FloatingPointError("the colour trunk's features are not finite (its weights?)")
    return features.astype(np.float16 if np.abs(features).max() < HALF_MAX else np.float32)


def _readable(path: Path) -> bool:
    try:
        with np.load(path) as z:
            return all(key in z for key in FLIPS)
    except UNREADABLE_CACHE:
        return False


@torch.no_grad()
def cache_color_features(
    records: Sequence[FrameRois],
    trunk: VGG16Trunk,
    scale: float,
    device: torch.device,
    bf16: bool,
    progress: bool = True,
) -> tuple[str, int]:
    """Compute and cache the features of every record (both flips) not cached yet; returns the
    trunk's digest and how many frames were computed. The trunk runs in eval mode, one image at a
    time (frames differ in size), under bfloat16 autocast with ``bf16``."""
    digest = trunk_digest(trunk)
    missing = [r for r in records if not _readable(features_path(r, scale, digest))]
    was_training = trunk.training
    trunk.eval()
    for record in tqdm(missing, desc="colour features", unit="frame", disable=not progress):
        scaled = load_scaled_frame(record, scale)
        maps = {}
        for name, frame in zip(FLIPS, (scaled, scaled.flipped()), strict=True):
            image = torch.from_numpy(color_input(np.ascontiguousarray(frame.color)))[None].to(device)
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                maps[name] = trunk(image.contiguous(memory_format=torch.channels_last))[0]
            maps[name] = _stored(maps[name].float().cpu().numpy())
        atomic_write(features_path(record, scale, digest), lambda f, m=maps: np.savez(f, **m))
    trunk.train(was_training)
    return digest, len(missing)
