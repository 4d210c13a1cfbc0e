"""The RoI database: per training frame, the labelled RoIs and the 3D boxes they regress from and to.

Per frame (docs/conventions.md "Proposals and initial 3D boxes", "Training"):

- RoIs are the ground truth's visible boxes (``box2d_visible``, the paper's ``gt2d_sel``), added
  as in Fast R-CNN, then, with ``data.detector_rois``, boxes jittered from them as a 2D
  detector's are (a3d.train.detector_rois), followed by the runtime's class-agnostic segment
  proposals (or the frame's precomputed ``NAME.proposals.npz``).
- Labels by 2D IoU with the visible boxes: foreground (the best box's class) at IoU >= fg_iou,
  background for IoU in [bg_iou_low, fg_iou); other proposals are dropped.
- Each RoI's segment (a ground truth's instance mask, a proposal's segment) is lifted to a 3D
  centre by the runtime's front end (hole filling, ``a3d.runtime.frontend.frame_proposals``,
  ``a3d.runtime.frontend.lifting``; proposals without any depth are dropped, as a3d-run drops
  them); a foreground
  RoI's initial 3D box is that centre with the mean size of its ground truth's class over the
  training set (theta 0). Its 3D target is the matched ground-truth box, its 2D target the
  ground truth's amodal 2D box.

The expensive part, the front end, depends on the frame and the proposal configuration only: it
runs once per frame and is cached as ``CACHE/NAME-KEY.npz`` (proposal boxes, lifted centres)
and ``CACHE/NAME-KEY.filled.npy`` (the hole-filled depth, which the mini-batches read instead of
filling the holes again), where KEY hashes the proposal config and the frame files' sizes and
modification times. Labels and initial boxes are cheap and rebuilt in memory on every run (they
depend on the class mean sizes of the whole training set).
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import zipfile
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.frame_proposals import frame_proposals
from a3d.runtime.frontend.lifting import initial_boxes, lift
from a3d.runtime.frontend.proposals import ProposalConfig
from a3d.runtime.io.atomic import atomic_write
from a3d.runtime.sources.folder import (
    FrameRef,
    list_frames,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
)
from a3d.runtime.structures.boxes import SIZE, boxes_array, empty_boxes
from a3d.runtime.structures.classes import CLASSES, NUM_CLASSES, from_softmax, to_softmax
from a3d.runtime.structures.frame import GroundTruth
from a3d.runtime.structures.geometry import Intrinsics, iou_2d
from a3d.train.detector_rois import detector_like_rois

CACHE_VERSION = 3
FILLED_DEPTH_SUFFIX = ".filled.npy"
# What np.load of a cached .npz raises when the file is from another version or cut short: the
# cache computes it again.
UNREADABLE_CACHE = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile)
MIN_VISIBLE_AREA = 1.0  # px^2: a ground truth with a smaller visible box has no RoI


@dataclass
class FrontEnd:
    """What a training frame needs from the (slow) front end: lifted proposals and GT segments."""

    image_size: tuple[int, int]
    proposal_boxes: np.ndarray  # (N, 4) liftable proposals only (the runtime drops the others)
    proposal_centers: np.ndarray  # (N, 3)
    gt_centers: np.ndarray  # (G, 3), one per ground-truth object
    gt_valid: np.ndarray  # (G,) bool


def ground_truth_masks(ref: FrameRef, gt: GroundTruth, image_size: tuple[int, int]) -> np.ndarray:
    """(G, H, W) segment of each object: its pixels in ``NAME.instances.png``, or, where the frame
    has no instance map or the object no pixel in it, the rectangle of its visible box."""
    h, w = image_size
    instances = read_instances(ref)
    masks = np.zeros((len(gt.class_ids), h, w), dtype=bool)
    v, u = np.arange(h)[:, None], np.arange(w)[None, :]
    for i, (box, instance) in enumerate(zip(gt.boxes2d_visible, gt.instance_ids, strict=True)):
        if instances is not None and instance > 0:
            masks[i] = instances == instance
        if not masks[i].any():  # pixel (u, v) is inside when its centre is
            masks[i] = (u >= box[0]) & (u <= box[2]) & (v >= box[1]) & (v <= box[3])
    return masks


def compute_front_end(
    ref: FrameRef, gt: GroundTruth, intrinsics: Intrinsics | None, config: ProposalConfig
) -> tuple[FrontEnd, np.ndarray]:
    """The runtime's front end on one frame, as a3d-run runs it (hole filling, its proposals or
    NAME.proposals.npz, lifting), plus the lifted ground-truth segments; and the filled depth."""
    frame = read_frame(ref, intrinsics, with_proposals=True)
    filled = fill_depth(frame.depth)
    segments, boxes = frame_proposals(frame.color, filled, frame.intrinsics, config, frame.proposals)
    centers = np.zeros((0, 3))
    if len(boxes):
        lifted = lift(segments, frame.depth, filled, frame.intrinsics)
        boxes, centers = boxes[lifted.valid], lifted.centers[lifted.valid]
    if len(gt.class_ids):
        masks = ground_truth_masks(ref, gt, frame.image_size)
        lifted = lift(masks, frame.depth, filled, frame.intrinsics)
        gt_centers, gt_valid = lifted.centers, lifted.valid
    else:
        gt_centers, gt_valid = np.zeros((0, 3)), np.zeros(0, dtype=bool)
    return FrontEnd(frame.image_size, boxes, centers, gt_centers, gt_valid), filled


Folders = str | os.PathLike | Sequence[str | os.PathLike]  # one frame folder, or several


@dataclass
class FrameRois:
    """The RoIs of one training frame, all at native resolution: the F foreground RoIs first
    (ground-truth RoIs first among them), then the background ones. Only the foreground rows
    have 3D boxes and targets, so those arrays hold F rows (this keeps the database small enough
    to hand to DataLoader worker processes)."""

    name: str
    ref: FrameRef
    filled_depth_path: Path  # the front end's hole-filled depth (H, W) float32, in the cache
    image_size: tuple[int, int]  # (H, W)
    boxes: np.ndarray  # (R, 4) float32 RoI boxes [x1, y1, x2, y2]
    labels: np.ndarray  # (R,) int64 softmax index: 0 background, 1 + class index foreground
    overlaps: np.ndarray  # (R,) float32 max IoU with a visible ground-truth box
    init_boxes: np.ndarray  # (F, 7) initial 3D box of the RoI's class
    gt_boxes3d: np.ndarray  # (F, 7) matched ground-truth 3D box
    gt_boxes2d: np.ndarray  # (F, 4) matched ground-truth amodal 2D box
    has_3d: np.ndarray  # (F,) bool: the segment could be lifted, so a 3D target exists
    folder_intrinsics: Intrinsics | None = None  # its folder's intrinsics.json (None: NAME.meta.json's)

    @property
    def num_fg(self) -> int:
        return len(self.has_3d)


@dataclass
class RoiDB:
    records: list[FrameRois]
    mean_sizes: np.ndarray  # (19, 3) [l, w, h] per class, metres
    skipped: list[str]  # "NAME: why" for frames left out


def class_mean_sizes(truths: Sequence[GroundTruth]) -> np.ndarray:
    """(19, 3) mean [l, w, h] per class over the training ground truth.

    A class absent from the training set gets the mean over all objects (1 m cubes if there are
    none), so every class still has an initial box.
    """
    ids = np.concatenate([np.asarray(t.class_ids, np.int64) for t in truths] or [np.zeros(0, np.int64)])
    sizes = np.concatenate([boxes_array(t.boxes3d)[:, SIZE] for t in truths] or [np.zeros((0, 3))])
    fallback = sizes.mean(axis=0) if len(sizes) else np.ones(3)
    counts = np.bincount(ids, minlength=NUM_CLASSES)[:, None]
    sums = np.zeros((NUM_CLASSES, 3))
    np.add.at(sums, ids, sizes)
    return np.where(counts > 0, sums / np.maximum(counts, 1), fallback)


def label_rois(
    rois: np.ndarray, gt: GroundTruth, fg_iou: float, bg_iou_low: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Match RoIs to visible ground-truth boxes.

    Returns (keep (R,) bool, labels (R,) softmax index, overlaps (R,), gt_index (R,) -1 if none):
    foreground at IoU >= fg_iou, background at IoU in [bg_iou_low, fg_iou), the rest not kept.
    """
    n = len(rois)
    if n == 0 or len(gt.class_ids) == 0:
        overlaps, gt_index = np.zeros(n), np.zeros(n, dtype=np.int64)
    else:
        iou = iou_2d(np.asarray(rois, np.float64), np.asarray(gt.boxes2d_visible, np.float64))
        gt_index = np.argmax(iou, axis=1)
        overlaps = iou[np.arange(n), gt_index]
    fg = overlaps >= fg_iou
    bg = (overlaps >= bg_iou_low) & ~fg
    labels = np.zeros(n, dtype=np.int64)
    labels[fg] = to_softmax(np.asarray(gt.class_ids, np.int64)[gt_index[fg]])
    gt_index = np.where(fg, gt_index, -1)
    return fg | bg, labels.astype(np.int64), overlaps.astype(np.float32), gt_index.astype(np.int64)


def frame_rois(
    ref: FrameRef,
    gt: GroundTruth,
    front: FrontEnd,
    filled_depth_path: Path,
    mean_sizes: np.ndarray,
    fg_iou: float,
    bg_iou_low: float,
    extra: tuple[np.ndarray, np.ndarray] | None = None,
) -> FrameRois:
    """One frame's record from its ground truth and its (cached) front-end results; ``extra``
    (boxes (M, 4), lifted centres (M, 3)) are more RoIs, after the ground truth's (the
    detector-like ones of a3d.train.detector_rois)."""
    visible = np.asarray(gt.boxes2d_visible, np.float64)
    gt_rows = np.flatnonzero(_has_pixels(visible))
    extra_boxes, extra_centers = extra if extra is not None else (np.zeros((0, 4)), np.zeros((0, 3)))
    others = np.concatenate([extra_boxes, np.asarray(front.proposal_boxes, np.float64)])
    boxes = np.concatenate([visible[gt_rows], others])
    centers = np.concatenate([front.gt_centers[gt_rows], extra_centers, front.proposal_centers])
    valid = np.concatenate([front.gt_valid[gt_rows], np.ones(len(others), bool)])
    keep, labels, overlaps, gt_index = label_rois(boxes, gt, fg_iou, bg_iou_low)
    kept = np.flatnonzero(keep)
    order = kept[np.argsort(labels[kept] == 0, kind="stable")]  # foreground first, in RoI order
    boxes, centers, valid = boxes[order], centers[order], valid[order]
    labels, overlaps, gt_index = labels[order], overlaps[order], gt_index[order]
    fg = int((labels > 0).sum())
    init = (
        initial_boxes(centers[:fg], mean_sizes)[np.arange(fg), from_softmax(labels[:fg])]
        if fg
        else empty_boxes()
    )
    return FrameRois(
        name=ref.name,
        ref=ref,
        filled_depth_path=filled_depth_path,
        image_size=front.image_size,
        boxes=boxes.astype(np.float32),
        labels=labels,
        overlaps=overlaps,
        init_boxes=init,
        gt_boxes3d=boxes_array(gt.boxes3d)[gt_index[:fg]],
        gt_boxes2d=np.asarray(gt.boxes2d_amodal, np.float64).reshape(-1, 4)[gt_index[:fg]],
        has_3d=valid[:fg].astype(bool),
    )


def _has_pixels(visible: np.ndarray) -> np.ndarray:
    """(G,) bool: the visible boxes large enough to be an RoI."""
    return (visible[:, 2] - visible[:, 0]) * (visible[:, 3] - visible[:, 1]) >= MIN_VISIBLE_AREA


def _detector_rois(
    ref: FrameRef,
    gt: GroundTruth,
    intrinsics: Intrinsics | None,
    filled: Path,
    mean_sizes: np.ndarray,
    config,
) -> tuple[np.ndarray, np.ndarray]:
    """The frame's ``data.detector_rois`` detector-like RoIs per object that have depth (the runtime
    drops a detector's box without any): (boxes (M, 4), centres (M, 3))."""
    visible = np.asarray(gt.boxes2d_visible, np.float64)
    rows = np.flatnonzero(_has_pixels(visible))
    frame = read_frame(ref, intrinsics)
    data = config.data
    boxes, centers, valid = detector_like_rois(
        ref.name, visible[rows], np.asarray(gt.class_ids)[rows], data.detector_rois, config.solver.seed,
        frame.depth, np.load(filled), frame.intrinsics, mean_sizes,
    )  # fmt: skip
    return boxes[valid], centers[valid]


def build_roidb(
    folders: Folders,
    config,
    cache_dir: str | os.PathLike,
    mean_sizes: np.ndarray | None = None,
    progress: bool = False,
) -> RoiDB:
    """The RoI database of every annotated frame in ``folders`` (one or several frame folders,
    each with its own intrinsics.json; ``config``: a TrainConfig).

    ``mean_sizes`` (19, 3) fixes the class mean sizes (a resumed run passes its checkpoint's);
    by default they are computed from all the folders' ground truth. Frames without ground truth
    or without any RoI are skipped and listed in ``RoiDB.skipped``; a folder without a single
    annotated frame is an InputError.
    """
    folders = [folders] if isinstance(folders, (str, os.PathLike)) else list(folders)
    annotated, skipped = [], []
    for folder in folders:
        intrinsics = read_folder_intrinsics(folder)
        count = len(annotated)
        for ref in list_frames(folder):
            gt = read_ground_truth(ref)
            if gt is None:
                skipped.append(f"{ref.name}: no ground truth")
            else:
                annotated.append((ref, gt, intrinsics))
        if len(annotated) == count:
            raise InputError(f"{folder}: no annotated frames (NAME.gt.json) to train on")
    if mean_sizes is None:
        mean_sizes = class_mean_sizes([gt for _, gt, _ in annotated])
    records = []
    for (ref, gt, intrinsics), front in zip(
        annotated, _front_ends(annotated, config, cache_dir, progress), strict=True
    ):
        filled = _cache_path(ref, config.proposals, cache_dir, FILLED_DEPTH_SUFFIX)
        extra = None
        if config.data.detector_rois:
            extra = _detector_rois(ref, gt, intrinsics, filled, mean_sizes, config)
        record = frame_rois(
            ref, gt, front, filled, mean_sizes, config.data.fg_iou, config.data.bg_iou_low, extra
        )
        record.folder_intrinsics = intrinsics
        if len(record.labels):
            records.append(record)
        else:
            skipped.append(f"{ref.name}: no foreground or background RoI")
    if not records:
        raise InputError(f"{', '.join(map(str, folders))}: no frame has a single training RoI")
    return RoiDB(records, np.asarray(mean_sizes, np.float64), skipped)


def _front_ends(
    annotated: list[tuple[FrameRef, GroundTruth, Intrinsics | None]],
    config,
    cache_dir: str | os.PathLike,
    progress: bool,
):
    """cached_front_end of every frame, in order; uncached frames in ``data.front_end_workers`` processes."""
    compute = partial(cached_front_end, proposal_config=config.proposals, cache_dir=cache_dir)
    refs, truths, intrinsics = (list(column) for column in zip(*annotated, strict=True))
    workers = config.data.front_end_workers or os.cpu_count() or 1
    missing = sum(not _is_cached(ref, config.proposals, cache_dir) for ref in refs)
    bar = partial(tqdm, total=len(annotated), desc="RoI database", disable=not progress, unit="frame")
    if workers == 1 or missing < 2 * workers:
        yield from bar(map(compute, refs, truths, intrinsics))
        return
    # spawn, not fork: the training process may already run torch's thread pools.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(min(workers, missing), mp_context=context) as pool:
        yield from bar(pool.map(compute, refs, truths, intrinsics, chunksize=4))


def _cache_path(
    ref: FrameRef, proposal_config: ProposalConfig, cache_dir: str | os.PathLike, suffix: str = ".npz"
) -> Path:
    return Path(cache_dir) / f"{ref.name}-{cache_key(ref, proposal_config)}{suffix}"


def _is_cached(ref: FrameRef, proposal_config: ProposalConfig, cache_dir: str | os.PathLike) -> bool:
    return all(
        _cache_path(ref, proposal_config, cache_dir, s).is_file() for s in (".npz", FILLED_DEPTH_SUFFIX)
    )


def cache_key(ref: FrameRef, proposal_config) -> str:
    """Hash of the proposal configuration and the frame's files (size, mtime): stale caches miss."""
    files = (ref.color_path, ref.depth_path, ref.meta_path, ref.gt_path, ref.instances_path,
             ref.proposals_path)  # fmt: skip
    stamps = [[str(p), os.stat(p).st_size, os.stat(p).st_mtime_ns] for p in files if p is not None]
    blob = json.dumps([CACHE_VERSION, asdict(proposal_config), stamps], sort_keys=True, default=str)
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def cached_front_end(
    ref: FrameRef,
    gt: GroundTruth,
    intrinsics: Intrinsics | None,
    proposal_config: ProposalConfig,
    cache_dir: str | os.PathLike,
) -> FrontEnd:
    """Proposals and lifted centres of one frame (and of its ground-truth segments), cached on disk
    with the frame's filled depth; computed only when either file is missing or unreadable."""
    path = _cache_path(ref, proposal_config, cache_dir)
    if _is_cached(ref, proposal_config, cache_dir):
        try:
            with np.load(path) as z:
                arrays = {k: z[k] for k in z.files}
            arrays["image_size"] = tuple(int(v) for v in arrays["image_size"])
            return FrontEnd(**arrays)
        except UNREADABLE_CACHE:
            pass  # unreadable (a file from another version, or cut short): recompute
    front, filled = compute_front_end(ref, gt, intrinsics, proposal_config)
    atomic_write(
        _cache_path(ref, proposal_config, cache_dir, FILLED_DEPTH_SUFFIX), lambda f: np.save(f, filled)
    )
    arrays = {k: np.asarray(v) for k, v in asdict(front).items()}
    atomic_write(path, lambda f: np.savez(f, **arrays))  # last: it marks the frame as cached
    return front


def describe(db: RoiDB) -> dict:
    """Counts for the log: frames, RoIs, foreground RoIs per class."""
    fg_per_class = np.zeros(NUM_CLASSES, dtype=np.int64)
    for r in db.records:
        fg_per_class += np.bincount(from_softmax(r.labels[r.labels > 0]), minlength=NUM_CLASSES)
    return {
        "frames": len(db.records),
        "rois": int(sum(len(r.labels) for r in db.records)),
        "fg_rois": int(fg_per_class.sum()),
        "fg_per_class": {c: int(n) for c, n in zip(CLASSES, fg_per_class, strict=True) if n},
        "skipped": len(db.skipped),
    }
