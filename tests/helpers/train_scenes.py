"""Tiny ray-cast RGB-D scenes with exact ground truth and a tiny config, for the training tests.

Not a3d.synth: a tiny network must learn these within a few iterations, so each class has its
own colour and size range, the frames are 48 x 64 and the ground truth is exact.

A scene: camera 1 m above a floor (camera y down, so the floor is the plane y = 1), a wall at
z = 6 m, and 2-3 axis-aligned boxes standing on the floor, each of a class with its own size
range and colour, so a tiny network can learn to tell them apart. Depth is the exact ray-cast
distance (z) with a few holes; the instance map, ``box2d_visible`` (extent of the visible
pixels) and ``box2d_amodal`` (``project_boxes_to_2d``) follow the README conventions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from a3d.runtime.sources.folder import write_frame, write_intrinsics
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, boxes_from_pixel_bounds, project_boxes_to_2d

SIZE = (48, 64)  # (H, W)
K = Intrinsics(fx=48.0, fy=48.0, cx=31.7, cy=23.6)
# class -> (l range, w range, h range) in metres, BGR colour
KINDS = {
    "chair": ((0.5, 0.6), (0.45, 0.5), (0.8, 1.0), (40, 40, 200)),
    "table": ((1.2, 1.6), (0.7, 0.9), (0.7, 0.8), (40, 160, 60)),
    "bed": ((1.9, 2.1), (1.4, 1.6), (0.5, 0.6), (200, 80, 40)),
}


def render_scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, GroundTruth]:
    """(colour BGR uint8, depth float32 m with holes, instances uint16, ground truth) of one scene."""
    rng = np.random.default_rng(seed)
    h, w = SIZE
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    dx, dy = (u - K.cx) / K.fx, (v - K.cy) / K.fy  # ray direction with z = 1: hit distance t = z
    floor = np.where(dy > 1e-6, 1.0 / np.maximum(dy, 1e-6), np.inf)
    depth = np.minimum(floor, 6.0)
    grey, beige = np.array([120.0, 120.0, 120.0]), np.array([170.0, 200.0, 215.0])
    color = np.where((floor < 6.0)[..., None], grey, beige)
    instances = np.zeros((h, w), np.uint16)
    names, boxes = [], []
    n = int(rng.integers(2, 4))
    xs = np.linspace(-1.2, 1.2, n) + rng.uniform(-0.2, 0.2, n)
    for i, name in enumerate(rng.choice(list(KINDS), n)):
        (l0, l1), (w0, w1), (h0, h1), bgr = KINDS[str(name)]
        size = np.array([rng.uniform(l0, l1), rng.uniform(w0, w1), rng.uniform(h0, h1)])
        centre = np.array([xs[i], 1.0 - size[2] / 2, rng.uniform(2.8, 4.5)])
        lo = centre - np.array([size[0], size[2], size[1]]) / 2  # (x, y, z) extents = (l, h, w)
        hi = centre + np.array([size[0], size[2], size[1]]) / 2
        t1 = np.stack([lo[0] / dx, lo[1] / dy, np.full_like(dx, lo[2])])
        t2 = np.stack([hi[0] / dx, hi[1] / dy, np.full_like(dx, hi[2])])
        t_in, t_out = np.minimum(t1, t2).max(axis=0), np.maximum(t1, t2).min(axis=0)
        hit = (t_out >= t_in) & (t_in > 0) & (t_in < depth)
        depth = np.where(hit, t_in, depth)
        instances[hit] = i + 1
        shade = 0.8 + 0.2 * rng.random((h, w, 1))
        color = np.where(hit[..., None], np.array(bgr) * shade, color)
        names.append(str(name))
        boxes.append([*centre, *size, 0.0])
    boxes3d = np.array(boxes)
    ids = np.arange(1, n + 1)
    visible = np.zeros((n, 4))
    present = np.zeros(n, bool)
    for i in range(n):
        vv, uu = np.nonzero(instances == i + 1)
        if len(uu):
            present[i] = True
            visible[i] = boxes_from_pixel_bounds([uu.min(), vv.min(), uu.max(), vv.max()])
    amodal = project_boxes_to_2d(boxes3d, np.eye(3), K, SIZE)
    kept = [c for c, p in zip(names, present, strict=True) if p]
    gt = GroundTruth.from_classes(kept, boxes3d[present], visible[present], amodal[present], ids[present])
    depth = depth.astype(np.float32)
    depth[rng.random((h, w)) < 0.03] = 0.0
    color = np.clip(color + rng.normal(0, 4, color.shape), 0, 255).astype(np.uint8)
    return color, depth, instances, gt


def write_scenes(folder: Path, count: int, seed: int = 0) -> Path:
    """``count`` scenes as frames NAME = s000, s001, ... with intrinsics, R_tilt = I, GT, instances."""
    folder.mkdir(parents=True, exist_ok=True)
    write_intrinsics(folder, K)
    for i in range(count):
        color, depth, instances, gt = render_scene(seed * 1000 + i)
        write_frame(folder, f"s{i:03d}", color, depth, R_tilt=np.eye(3), gt=gt, instances=instances)
    return folder


TINY = (
    "net.width=0.0625",
    "net.fuse_channels=16",
    "net.fc6=32",
    "net.fc7=32",
    "proposals.min_area=20",
    "proposals.scale=1",
    "proposals.superpixels.n_segments=120",
    "data.rois_per_image=32",
    "data.workers=0",
    "data.front_end_workers=1",
    "solver.threads=1",
    "log.progress=false",
    "log.log_every=1",
)
"""``--set`` overrides of a network and pipeline small enough for the tests' 48 x 64 scenes."""


def tiny_train_args(frames: Path | list[Path], run: Path, cache: Path, *sets: str) -> list[str]:
    """a3d-train's arguments for these scenes: ``frames`` (one folder or several) into ``run``, the
    vgg16 preset shrunk by TINY on the CPU, proposals cached in ``cache``, then ``sets`` (--set)."""
    folders = frames if isinstance(frames, list) else [frames]
    overrides = [*TINY, f"data.cache_dir={cache}", *sets]
    return [*map(str, folders), "--out", str(run), "--config", "vgg16", "--device", "cpu",
            *[a for s in overrides for a in ("--set", s)]]  # fmt: skip
