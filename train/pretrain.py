"""Colour-crop classification pretraining of a VGG16 trunk: a3d's stand-in for ImageNet weights.

The paper starts both trunks from ImageNet VGG16 (docs/conventions.md "Network"). Nothing can be downloaded
here, and a width-scaled trunk has no ImageNet weights anyway, so a3d-pretrain does what ImageNet
pretraining does on data that exists: it trains the configuration's VGG16 trunk (width,
BatchNorm) with VGG's classifier (fc6, fc7, output) to classify colour crops of the annotated
objects of a folder of frames, plus background crops: colour only, no depth, no 3D boxes. The
result is written in torchvision's VGG16 key layout (BatchNorm folded into the convs, conv1_1 in
torchvision's RGB / std input convention), so ``solver.pretrained`` loads it exactly as it loads
ImageNet weights (a3d.train.model.weights): the same convs into both trunks, fc6 / fc7 where the
shapes allow. Use frames disjoint from the detector's training and test frames (a3d-synth with
another seed), as ImageNet is disjoint from NYUv2.

A crop is an object's visible box (the paper's gt2d_sel) grown by ``CROP_MARGIN`` and warped to
``crop + crop // 8`` pixels square; training takes random ``crop``-pixel windows of it and flips
them (AlexNet's augmentation), validation the centre window. At crop 112 the trunk's conv5_3 map
is 7 x 7, the size RoI pooling gives fc6 in the detector.
"""

from __future__ import annotations

import copy
import json
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from a3d.runtime.errors import InputError
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.network.preprocess import COLOR_MEAN_BGR
from a3d.runtime.sources.folder import list_frames, read_folder_intrinsics, read_frame, read_ground_truth
from a3d.runtime.structures.classes import NUM_CLASSES, to_softmax
from a3d.runtime.structures.geometry import iou_2d
from a3d.train.checkpoint import atomic_torch_save
from a3d.train.config import PretrainConfig
from a3d.train.loop import param_groups
from a3d.train.model.config import NetConfig
from a3d.train.model.vgg import FEATURE_STRIDE, VGG16Trunk, conv5_size
from a3d.train.model.weights import torchvision_first_conv

CROP_MARGIN = 1.25  # crop side / visible box side (some context around the object)
MIN_BOX_PX = 12  # objects whose visible box is narrower or lower are skipped
BACKGROUND_SHARE = 0.25  # background crops per object crop
BACKGROUND_MAX_IOU = 0.3  # a background crop overlaps no visible box more than this
FIT_SAMPLE = 2000  # training crops the reported training accuracy is measured on


class CropClassifier(nn.Module):
    """VGG16Trunk + torchvision's VGG classifier layout (classifier.0 fc6, .3 fc7, .6 output)."""

    def __init__(self, net: NetConfig, crop: int, classes: int = NUM_CLASSES + 1) -> None:
        super().__init__()
        self.trunk = VGG16Trunk(net.width, batch_norm=net.trunk_norm)
        rows, cols = conv5_size(crop, crop)
        if (rows, cols) != (net.pool_size, net.pool_size):
            need = net.pool_size * FEATURE_STRIDE
            raise ValueError(f"crop {crop} gives a {rows}x{cols} conv5_3 map; fc6 needs {net.pool_size}x"
                             f"{net.pool_size} (crop {need})")  # fmt: skip
        self.classifier = nn.Sequential(
            nn.Linear(self.trunk.out_channels * rows * cols, net.fc6),
            nn.ReLU(inplace=True),
            nn.Dropout(net.dropout),
            nn.Linear(net.fc6, net.fc7),
            nn.ReLU(inplace=True),
            nn.Dropout(net.dropout),
            nn.Linear(net.fc7, classes),
        )

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.classifier(self.trunk(images).flatten(1))


@dataclass
class Crops:
    """Warped colour crops (N, S, S, 3) uint8 BGR with labels (N,) (0 background, 1 + CLASSES
    index) and the index of the frame each came from."""

    images: np.ndarray
    labels: np.ndarray
    frames: np.ndarray


def frame_crops(bgr: np.ndarray, boxes: np.ndarray, class_ids: np.ndarray, size: int,
                rng: np.random.Generator) -> tuple[list[np.ndarray], list[int]]:  # fmt: skip
    """The object crops of one frame and BACKGROUND_SHARE as many background crops."""
    h, w = bgr.shape[:2]
    crops, labels = [], []
    sides = []
    for box, cls in zip(boxes, class_ids, strict=True):
        bw, bh = box[2] - box[0], box[3] - box[1]
        if min(bw, bh) < MIN_BOX_PX:
            continue
        crops.append(_warp(bgr, box, size))
        labels.append(int(to_softmax(cls)))
        sides.append((bw, bh))
    for _ in range(int(rng.binomial(len(sides), BACKGROUND_SHARE)) if sides else 0):
        for _attempt in range(10):  # rejection sampling: a box of an object's size, off the objects
            bw, bh = sides[int(rng.integers(len(sides)))]
            x0, y0 = rng.uniform(0, max(w - bw, 1)), rng.uniform(0, max(h - bh, 1))
            box = np.array([x0, y0, x0 + bw, y0 + bh])
            if iou_2d(box[None], boxes).max() <= BACKGROUND_MAX_IOU:  # sides: boxes is not empty
                crops.append(_warp(bgr, box, size))
                labels.append(0)
                break
    return crops, labels


def _warp(bgr: np.ndarray, box: np.ndarray, size: int) -> np.ndarray:
    """The box grown by CROP_MARGIN about its centre, warped to size x size (borders replicated)."""
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    half_w, half_h = CROP_MARGIN * (box[2] - box[0]) / 2, CROP_MARGIN * (box[3] - box[1]) / 2
    src = np.float32([[cx - half_w, cy - half_h], [cx + half_w, cy - half_h], [cx - half_w, cy + half_h]])
    dst = np.float32([[0, 0], [size, 0], [0, size]])
    return cv2.warpAffine(bgr, cv2.getAffineTransform(src, dst), (size, size), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)  # fmt: skip


def load_crops(folder: str | os.PathLike, size: int, seed: int, progress: bool = True) -> Crops:
    """Crops of every annotated frame of ``folder`` (a3d's frame format)."""
    refs = [ref for ref in list_frames(folder) if ref.gt_path is not None]
    if not refs:
        raise InputError(f"{folder}: no annotated frames (NAME.gt.json) to take crops from")
    intrinsics = read_folder_intrinsics(folder)
    rng = np.random.default_rng(seed)
    images, labels, frames = [], [], []
    for i, ref in enumerate(tqdm(refs, desc="a3d-pretrain: crops", unit="frame", disable=not progress)):
        gt = read_ground_truth(ref)
        crops, crop_labels = frame_crops(read_frame(ref, intrinsics).color, gt.boxes2d_visible, gt.class_ids,
                                         size, rng)  # fmt: skip
        images += crops
        labels += crop_labels
        frames += [i] * len(crops)
    if not images:
        raise InputError(f"{folder}: no object of at least {MIN_BOX_PX} px to take crops from")
    return Crops(np.stack(images), np.array(labels, np.int64), np.array(frames, np.int64))


def to_input(crops: np.ndarray) -> torch.Tensor:
    """(N, S, S, 3) uint8 BGR -> (N, 3, S, S) float32 minus the colour mean, as the colour trunk sees."""
    return torch.from_numpy(crops.astype(np.float32) - COLOR_MEAN_BGR).permute(0, 3, 1, 2).contiguous()


def torchvision_state(model: CropClassifier) -> dict[str, torch.Tensor]:
    """The model in torchvision's VGG16 key layout: BatchNorm folded (eval statistics), conv1_1
    converted from a3d's input convention (BGR 0..255 minus mean) to torchvision's (RGB, /255,
    / std), so that a3d.train.model.weights's conversion gives the trained conv1_1 back."""
    trunk = copy.deepcopy(model.trunk).eval()
    trunk.fold_batch_norms()
    state = {f"features.{k}": v.detach().clone() for k, v in trunk.features.state_dict().items()}
    state["features.0.weight"] = torchvision_first_conv(state["features.0.weight"])
    state.update({f"classifier.{k}": v.detach().clone() for k, v in model.classifier.state_dict().items()})
    return state


@dataclass
class PretrainResult:
    """What a3d-pretrain reports (and writes to WEIGHTS.pt.json)."""

    iterations: int
    train_crops: int
    val_crops: int
    first_loss: float  # mean training loss of the first tenth of the iterations
    last_loss: float  # and of the last tenth
    train_accuracy: float  # top-1 on FIT_SAMPLE training crops' centre windows (how well it fits)
    val_accuracy: float  # top-1 over the held-out frames' crops (background included)
    val_balanced_accuracy: float  # mean per-label recall over the labels present


def pretrain(data: str | os.PathLike, out: str | os.PathLike, net: NetConfig, config: PretrainConfig,
             device: str = "cpu", progress: bool = True) -> PretrainResult:  # fmt: skip
    """Train a CropClassifier on ``data``'s crops and write its torchvision-layout weights to ``out``."""
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    pad = config.crop // 8
    crops = load_crops(data, config.crop + pad, config.seed, progress)
    n_frames = int(crops.frames.max()) + 1
    val_frames = rng.permutation(n_frames)[: round(config.val_share * n_frames)]
    is_val = np.isin(crops.frames, val_frames)
    train_idx, val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    if not len(train_idx):
        raise InputError(f"{data}: no training crops left after holding out {len(val_frames)} frames")

    model = CropClassifier(net, config.crop).to(device)
    groups = param_groups(model, config.weight_decay)  # decay on weights only, as a3d-train
    optimizer = torch.optim.SGD(groups, lr=config.lr, momentum=config.momentum)
    step_at = math.ceil(config.lr_step * config.iterations)
    bar = tqdm(range(config.iterations), desc="a3d-pretrain", unit="it", disable=not progress)
    order, cursor = rng.permutation(train_idx), 0
    model.train()
    losses = []
    for it in bar:
        if it == step_at:
            for group in optimizer.param_groups:
                group["lr"] *= 0.1
        if cursor + config.batch > len(order):
            order, cursor = rng.permutation(train_idx), 0
        batch = order[cursor : cursor + config.batch]
        cursor += config.batch
        images = _augment(crops.images[batch], config.crop, rng)
        loss = nn.functional.cross_entropy(model(to_input(images).to(device)),
                                           torch.from_numpy(crops.labels[batch]).to(device))  # fmt: skip
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{losses[-1]:.3f}")

    fitted = rng.choice(train_idx, min(len(train_idx), FIT_SAMPLE), replace=False)
    fit, _ = evaluate_crops(model, crops.images[fitted], crops.labels[fitted], config.crop, device)
    accuracy, balanced = evaluate_crops(
        model, crops.images[val_idx], crops.labels[val_idx], config.crop, device
    )
    atomic_torch_save(out, torchvision_state(model.cpu()))
    tenth = max(1, len(losses) // 10)
    result = PretrainResult(config.iterations, len(train_idx), len(val_idx), float(np.mean(losses[:tenth])),
                            float(np.mean(losses[-tenth:])), fit, accuracy, balanced)  # fmt: skip
    report = {**result.__dict__, "net": net.__dict__, "pretrain": config.__dict__}
    atomic_write_bytes(f"{out}.json", json.dumps(report, indent=1, default=str).encode("utf-8"))
    return result


def _augment(images: np.ndarray, crop: int, rng: np.random.Generator) -> np.ndarray:
    """A random crop x crop window of each image, flipped left-right half of the time."""
    n, size = len(images), images.shape[1]
    out = np.empty((n, crop, crop, 3), np.uint8)
    for i, (y, x) in enumerate(rng.integers(0, size - crop + 1, size=(n, 2))):
        window = images[i, y : y + crop, x : x + crop]
        out[i] = window[:, ::-1] if rng.random() < 0.5 else window
    return out


@torch.no_grad()
def evaluate_crops(model: CropClassifier, images: np.ndarray, labels: np.ndarray, crop: int,
                   device: str = "cpu", batch: int = 256) -> tuple[float, float]:  # fmt: skip
    """(top-1 accuracy, balanced accuracy) on the centre windows; (nan, nan) without crops."""
    if not len(images):
        return float("nan"), float("nan")
    model.eval()
    start = (images.shape[1] - crop) // 2
    centre = images[:, start : start + crop, start : start + crop]
    predicted = np.concatenate([model(to_input(centre[i : i + batch]).to(device)).argmax(1).cpu().numpy()
                                for i in range(0, len(centre), batch)])  # fmt: skip
    model.train()
    recalls = [np.mean(predicted[labels == c] == c) for c in np.unique(labels)]
    return float(np.mean(predicted == labels)), float(np.mean(recalls))
