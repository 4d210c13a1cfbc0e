"""Ready-to-train mini-batches, built in DataLoader worker processes.

``BatchDataset[iteration]`` is this rank's whole mini-batch of that iteration (the sampler's plan
is a pure function of the seed and the iteration, see a3d.train.sampler), so the DataLoader
iterates over iteration numbers and a resumed run simply starts at a later one. Per image:
take the colour image and the hole-filled depth the RoI database cached (the front end ran once
per frame there) resized to the input scale, from a cache of their own (a3d.train.scaled_frames;
with ``data.augment`` the frame is read, augmented, refilled and resized each time), flip when
the plan says so, compute the regression targets of the sampled foreground RoIs and normalise
them per class, and build the network inputs and RoIs with the runtime's own functions
(a3d.runtime.network.network_input).

Flip (README "Pixels and 2D boxes"): image and depth columns reversed, 2D boxes through
``flip_boxes_2d`` (u -> W - 1 - u), 3D boxes through ``flip_boxes_3d`` (x -> -x, theta -> -theta),
which is the mirror image under the flipped intrinsics (cx -> W - 1 - cx) and tilt
(R_tilt -> F R_tilt F). Targets are encoded from the flipped boxes, never patched by hand.

Target normalisation: per class (softmax index) mean and standard deviation of the raw targets
over all training foreground RoIs, in both flips when flipping is on (``TargetStats``); they are
saved in the checkpoint and undone at inference (``TargetStats.denormalise_*``).
"""

from __future__ import annotations

import signal
from dataclasses import dataclass, fields

import cv2
import numpy as np
import torch

from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.network.network_input import frame_network_inputs, with_batch_index
from a3d.runtime.postprocess.box_coder import encode_2d, encode_3d
from a3d.runtime.sources.folder import read_frame
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.runtime.structures.geometry import flip_boxes_2d, flip_boxes_3d
from a3d.train.augment import augment_frame, augment_rng
from a3d.train.color_features import load_color_features
from a3d.train.roidb import FrameRois
from a3d.train.sampler import plan_batch
from a3d.train.scaled_frames import load_scaled_frame

MIN_STD = 1e-3  # floor of a normalisation std (a class whose targets are all equal)


@dataclass
class TargetStats:
    """Per-class (softmax index, row 0 = background, unused) target means and stds."""

    mean3d: np.ndarray  # (20, 7)
    std3d: np.ndarray  # (20, 7)
    mean2d: np.ndarray  # (20, 4)
    std2d: np.ndarray  # (20, 4)

    @classmethod
    def identity(cls) -> TargetStats:
        zeros3d, ones3d = np.zeros((NUM_OUTPUTS, BOX_DIM)), np.ones((NUM_OUTPUTS, BOX_DIM))
        return cls(zeros3d, ones3d, np.zeros((NUM_OUTPUTS, 4)), np.ones((NUM_OUTPUTS, 4)))

    def normalise_3d(self, labels: np.ndarray, targets: np.ndarray) -> np.ndarray:
        return (targets - self.mean3d[labels]) / self.std3d[labels]

    def normalise_2d(self, labels: np.ndarray, targets: np.ndarray) -> np.ndarray:
        return (targets - self.mean2d[labels]) / self.std2d[labels]

    def denormalise_3d(self, deltas: np.ndarray) -> np.ndarray:
        """(..., 20, 7) normalised network deltas of every class -> raw deltas."""
        return deltas * self.std3d + self.mean3d

    def denormalise_2d(self, deltas: np.ndarray) -> np.ndarray:
        """(..., 20, 4) normalised network deltas of every class -> raw deltas."""
        return deltas * self.std2d + self.mean2d

    def to_tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: torch.from_numpy(np.asarray(getattr(self, f.name), np.float64)) for f in fields(self)}

    @classmethod
    def from_tensors(cls, data: dict) -> TargetStats:
        return cls(**{f.name: np.asarray(data[f.name], dtype=np.float64) for f in fields(cls)})


def raw_targets(record: FrameRois, rows: np.ndarray, flip: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unnormalised 3D (n, 7) and 2D (n, 4) targets of RoIs ``rows`` and the 3D mask (n,).

    Background rows (and foreground rows without an initial 3D box, for 3D) get zeros and mask
    False. With ``flip`` the boxes are mirrored first (README flip convention).
    """
    rows = np.asarray(rows, np.int64)
    fg = np.flatnonzero(rows < record.num_fg)  # foreground RoIs are the record's first rows
    t3d, t2d = np.zeros((len(rows), BOX_DIM)), np.zeros((len(rows), 4))
    has_3d = np.zeros(len(rows), bool)
    if len(fg) == 0:
        return t3d, t2d, has_3d
    idx = rows[fg]
    boxes, gt2d = record.boxes[idx].astype(np.float64), record.gt_boxes2d[idx]
    init, gt3d = record.init_boxes[idx], record.gt_boxes3d[idx]
    if flip:
        width = record.image_size[1]
        boxes, gt2d = flip_boxes_2d(boxes, width), flip_boxes_2d(gt2d, width)
        init, gt3d = flip_boxes_3d(init), flip_boxes_3d(gt3d)
    t2d[fg] = encode_2d(boxes, gt2d)
    lifted = record.has_3d[idx]
    has_3d[fg[lifted]] = True
    if lifted.any():
        t3d[fg[lifted]] = encode_3d(init[lifted], gt3d[lifted])
    return t3d, t2d, has_3d


def compute_target_stats(records: list[FrameRois], flip: bool) -> TargetStats:
    """Per-class mean and std of the raw targets over every foreground RoI (and its mirror image)."""
    labels3d, labels2d, all3d, all2d = [], [], [], []
    for record in records:
        rows = np.arange(record.num_fg)
        for flipped in (False, True) if flip else (False,):
            t3d, t2d, has_3d = raw_targets(record, rows, flipped)
            labels3d.append(record.labels[rows][has_3d])
            all3d.append(t3d[has_3d])
            labels2d.append(record.labels[rows])
            all2d.append(t2d)
    stats = TargetStats.identity()
    for labels, targets, mean, std in (
        (labels3d, all3d, stats.mean3d, stats.std3d),
        (labels2d, all2d, stats.mean2d, stats.std2d),
    ):
        if not labels:
            continue
        labels, targets = np.concatenate(labels), np.concatenate(targets)
        for c in np.unique(labels):
            rows = targets[labels == c]
            mean[c] = rows.mean(axis=0)
            std[c] = np.maximum(rows.std(axis=0), MIN_STD)
    return stats


def shape_groups(records: list[FrameRois]) -> np.ndarray:
    """One group id per record, shared by the frames of one (H, W) (the sampler batches them together)."""
    return np.unique([r.image_size for r in records], axis=0, return_inverse=True)[1].reshape(-1)


def pad_stack(images: list[np.ndarray]) -> np.ndarray:
    """(C, h_i, w_i) arrays -> (B, C, max h, max w), zero-padded at the bottom and right (= the mean)."""
    h = max(i.shape[1] for i in images)
    w = max(i.shape[2] for i in images)
    out = np.zeros((len(images), images[0].shape[0], h, w), dtype=np.float32)
    for b, image in enumerate(images):
        out[b, :, : image.shape[1], : image.shape[2]] = image
    return out


class BatchDataset(torch.utils.data.Dataset):
    """Item ``i`` is the mini-batch of iteration ``i`` for one rank, as a dict of tensors."""

    def __init__(
        self,
        records: list[FrameRois],
        stats: TargetStats,
        config,
        iterations: int,
        rank: int = 0,
        world_size: int = 1,
        color_features: str = "",
    ) -> None:
        self.records = records
        self.color_features = color_features  # a frozen colour trunk's digest: its cached features
        self.stats = stats
        self.data = config.data
        self.seed = config.solver.seed
        self.iterations = iterations
        self.rank, self.world_size = rank, world_size
        self.labels = [r.labels for r in records]
        self.groups = shape_groups(records) if config.data.group_by_shape else None

    def __len__(self) -> int:
        return self.iterations

    def __getitem__(self, iteration: int) -> dict:
        d = self.data
        plans = plan_batch(
            self.labels,
            seed=self.seed,
            iteration=int(iteration),
            images_per_batch=d.images_per_batch,
            rois_per_image=d.rois_per_image,
            fg_fraction=d.fg_fraction,
            flip=d.flip,
            rank=self.rank,
            world_size=self.world_size,
            groups=self.groups,
        )
        colors, maps, depths, rois, contexts, labels, t3ds, t2ds, w3ds = ([] for _ in range(9))
        for b, plan in enumerate(plans):
            record = self.records[plan.image]
            boxes = record.boxes[plan.rois].astype(np.float64)
            if plan.flip:
                boxes = flip_boxes_2d(boxes, record.image_size[1])
            if d.augment:  # a3d.train.augment: other light and sensors, same geometry (refilled)
                frame = read_frame(record.ref, record.folder_intrinsics)
                rng = augment_rng(self.seed, int(iteration), b)
                color, raw = augment_frame(rng, frame.color, frame.depth)
                depth = fill_depth(raw)
                if plan.flip:
                    color, depth = color[:, ::-1], depth[:, ::-1]
                color_in, depth_in, roi_boxes, context = frame_network_inputs(
                    color, depth, boxes, d.input_scale, d.depth_truncation_m, d.context_scale
                )
            else:  # the same pixels every epoch: resized once and cached (a3d.train.scaled_frames)
                scaled = load_scaled_frame(record, d.input_scale)
                scaled = scaled.flipped() if plan.flip else scaled
                color_in, depth_in, roi_boxes, context = scaled.network_inputs(
                    boxes, d.depth_truncation_m, d.context_scale
                )
            t3d, t2d, has_3d = raw_targets(record, plan.rois, plan.flip)
            roi_labels = record.labels[plan.rois]
            if self.color_features:  # the frozen colour trunk's output instead of its input
                maps.append(load_color_features(record, d.input_scale, self.color_features, plan.flip))
            else:
                colors.append(color_in)
            depths.append(depth_in)
            rois.append(with_batch_index(roi_boxes, b))
            contexts.append(with_batch_index(context, b))
            labels.append(roi_labels)
            t3ds.append(np.where(has_3d[:, None], self.stats.normalise_3d(roi_labels, t3d), 0.0))
            t2ds.append(np.where(roi_labels[:, None] > 0, self.stats.normalise_2d(roi_labels, t2d), 0.0))
            w3ds.append(has_3d.astype(np.float32))
        images = {"color_map": maps} if self.color_features else {"color": colors}
        return {
            **{key: torch.from_numpy(pad_stack(value)) for key, value in images.items()},
            "depth": torch.from_numpy(pad_stack(depths)),
            "rois": torch.from_numpy(np.concatenate(rois).astype(np.float32)),
            "context_rois": torch.from_numpy(np.concatenate(contexts).astype(np.float32)),
            "labels": torch.from_numpy(np.concatenate(labels).astype(np.int64)),
            "targets3d": torch.from_numpy(np.concatenate(t3ds).astype(np.float32)),
            "targets2d": torch.from_numpy(np.concatenate(t2ds).astype(np.float32)),
            "weights3d": torch.from_numpy(np.concatenate(w3ds)),
            "frames": [self.records[p.image].name for p in plans],
            "flips": [p.flip for p in plans],
        }


def batch_loader(dataset: BatchDataset, start: int, workers: int, pin_memory: bool = False):
    """Batches of iterations start .. len(dataset) - 1, in order, from ``workers`` processes.

    Workers are spawned, not forked: a fork of the training process, whose OpenCV and OpenMP
    thread pools have run (proposals, the network), can deadlock on a lock held by a thread that
    does not exist in the child. The loader gets its own torch.Generator so creating it never
    draws from the global RNG (which the training loop reseeds per iteration for dropout).
    """
    return torch.utils.data.DataLoader(
        dataset,
        batch_size=None,
        sampler=range(start, len(dataset)),
        num_workers=workers,
        pin_memory=pin_memory,
        prefetch_factor=2 if workers > 0 else None,
        generator=torch.Generator().manual_seed(0),
        worker_init_fn=_single_threaded,
        multiprocessing_context="spawn" if workers > 0 else None,
    )


def _single_threaded(_worker_id: int) -> None:
    """Workers leave the cores to the training process: one thread each for OpenCV and torch.
    They ignore Ctrl-C (which a terminal sends to the whole process group): the training process
    finishes its iteration and saves a checkpoint, and needs its workers until then."""
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
