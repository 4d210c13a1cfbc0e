"""The pure-torch reference detector: frame -> detections with the eager A3DNet.

This is the path the ONNX runtime is compared against, so everything except the network itself
is the runtime's own code (a3d.runtime): hole filling, gravity, proposals, lifting, initial
boxes, preprocessing, context boxes, decoding, NMS, corners and the detections format.

Per frame (SPEC.md "Inference and post-processing"):
1. fill the depth holes; R_tilt from the frame (``NAME.meta.json``) or estimated from depth;
2. segment proposals (or ``NAME.proposals.npz``), lifted to initial centres; proposals that
   cannot be lifted (no depth at all) are dropped;
3. the network scores every proposal and regresses class-specific 3D deltas, de-normalised with
   the training target statistics and decoded onto the per-class initial boxes (class mean size,
   theta 0); with ``regress_3d`` off the initial boxes are reported (the "-3dreg" ablation);
4. per class, the ``top_k`` best scores, then 2D NMS at ``nms_iou`` on the proposal boxes (per
   class); no NMS in 3D. ``box2d`` of a detection is its proposal box (what NMS and a3d-eval's
   NMS see); ``box3d`` is canonical (l >= w, theta in [-pi/2, pi/2]).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from a3d.runtime.box_coder import decode_3d
from a3d.runtime.classes import NUM_CLASSES, NUM_OUTPUTS
from a3d.runtime.depth import fill_depth
from a3d.runtime.detections_io import FrameDetections
from a3d.runtime.evaluation import EvalConfig, EvalResult, FrameTruth, evaluate
from a3d.runtime.frames import Frame, list_frames, read_folder_intrinsics, read_frame, read_ground_truth
from a3d.runtime.geometry import batched_nms_2d, box_corners_camera, canonical_boxes, context_boxes
from a3d.runtime.gravity import estimate_rtilt
from a3d.runtime.lifting import initial_boxes
from a3d.train.checkpoint import load_checkpoint
from a3d.train.config import InferenceConfig, TrainConfig
from a3d.train.dataset import CONTEXT_SCALE, TargetStats, network_inputs, scale_boxes, with_batch_index
from a3d.train.model import A3DNet
from a3d.train.roidb import Segments, cached_front_end, frame_segments

HEAD_CHUNK = 512  # RoIs per head pass (bounds the RoI pooling's memory at 2000 proposals)


@dataclass
class NetworkOutput:
    """Per proposal: softmax scores (N, 20) and raw (de-normalised) 3D deltas (N, 20, 7)."""

    scores: np.ndarray
    deltas3d: np.ndarray


def select_detections(
    scores: np.ndarray, boxes2d: np.ndarray, config: InferenceConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per class top-k then per-class 2D NMS. ``scores`` (N, 19) object-class scores.

    Returns (proposal index, class index (0-based), score) of the kept detections, by
    descending score.
    """
    n = len(scores)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    k = min(config.top_k, n)
    top = np.argpartition(-scores, k - 1, axis=0)[:k].T  # (19, k) proposal indices per class
    classes = np.repeat(np.arange(NUM_CLASSES), k)
    rows = top.reshape(-1)
    cand = scores[rows, classes]
    ok = cand >= config.min_score
    rows, classes, cand = rows[ok], classes[ok], cand[ok]
    keep = batched_nms_2d(boxes2d[rows], cand, classes, config.nms_iou)
    return rows[keep], classes[keep], cand[keep]


class TorchDetector:
    """A3DNet in eager torch plus the runtime's pre- and post-processing."""

    def __init__(
        self,
        model: A3DNet,
        config: TrainConfig,
        stats: TargetStats,
        mean_sizes: np.ndarray,
        device: torch.device | str = "cpu",
    ) -> None:
        self.device = torch.device(device)
        self.model = model.to(self.device)
        self.config = config
        self.stats = stats
        self.mean_sizes = np.asarray(mean_sizes, np.float64)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, device: torch.device | str = "cpu") -> TorchDetector:
        state = load_checkpoint(path)
        config = TrainConfig.from_json(state["config"], str(path))
        model = A3DNet(config.net)
        model.load_state_dict(state["model"])
        stats = TargetStats.from_tensors(state["target_stats"])
        return cls(model, config, stats, state["mean_sizes"].numpy(), device)

    def network(self, frame: Frame, depth_filled: np.ndarray, boxes: np.ndarray) -> NetworkOutput:
        """Scores and raw 3D deltas of proposal ``boxes`` (N, 4, native pixels), in eval mode."""
        was_training = self.model.training
        self.model.eval()
        try:
            with torch.no_grad():
                return self._network(frame, depth_filled, boxes)
        finally:
            self.model.train(was_training)

    def _network(self, frame: Frame, depth_filled: np.ndarray, boxes: np.ndarray) -> NetworkOutput:
        d = self.config.data
        color, depth, (sx, sy) = network_inputs(frame.color, depth_filled, d.scale, d.depth_truncation)
        context = context_boxes(boxes, frame.image_size, CONTEXT_SCALE)
        rois = torch.from_numpy(with_batch_index(scale_boxes(boxes, sx, sy), 0).astype(np.float32))
        ctx = torch.from_numpy(with_batch_index(scale_boxes(context, sx, sy), 0).astype(np.float32))
        features = self.model.trunk_features(
            torch.from_numpy(color)[None].to(self.device), torch.from_numpy(depth)[None].to(self.device)
        )
        logits, deltas = [], []
        for start in range(0, len(boxes), HEAD_CHUNK):
            part = slice(start, start + HEAD_CHUNK)
            lg, d3, _ = self.model.head(features, rois[part].to(self.device), ctx[part].to(self.device))
            logits.append(lg.float().cpu())
            deltas.append(d3.float().cpu())
        if not logits:
            return NetworkOutput(np.zeros((0, NUM_OUTPUTS)), np.zeros((0, NUM_OUTPUTS, 7)))
        scores = torch.softmax(torch.cat(logits), dim=1).double().numpy()
        raw = self.stats.denormalise_3d(torch.cat(deltas).double().numpy().reshape(-1, NUM_OUTPUTS, 7))
        return NetworkOutput(scores, raw)

    def detect(self, frame: Frame, segments: Segments | None = None) -> FrameDetections:
        """Detections of one frame; ``segments`` skips the proposal stage (a cached result)."""
        timing = {}
        t0 = time.perf_counter()
        filled = fill_depth(frame.depth)
        R_tilt = frame.R_tilt if frame.R_tilt is not None else estimate_rtilt(frame.depth, frame.intrinsics)
        t1 = time.perf_counter()
        timing["front_end"] = t1 - t0
        if segments is None:
            segments = frame_segments(frame, filled, self.config.proposals)
        valid = np.asarray(segments.valid, bool)
        boxes, centers = np.asarray(segments.boxes, np.float64)[valid], segments.centers[valid]
        t2 = time.perf_counter()
        timing["proposals"] = t2 - t1
        out = self.network(frame, filled, boxes)
        t3 = time.perf_counter()
        timing["network"] = t3 - t2
        rows, classes, scores = select_detections(out.scores[:, 1:], boxes, self.config.inference)
        init = initial_boxes(centers[rows], self.mean_sizes)[np.arange(len(rows)), classes]
        if self.config.inference.regress_3d and len(rows):
            boxes3d = decode_3d(init, out.deltas3d[rows, classes + 1])
        else:
            boxes3d = init
        boxes3d = canonical_boxes(boxes3d) if len(rows) else np.zeros((0, 7))
        timing["post"] = time.perf_counter() - t3
        return FrameDetections(
            frame=frame.name,
            R_tilt=np.asarray(R_tilt, np.float64),
            class_ids=classes.astype(np.int64),
            scores=scores.astype(np.float64),
            boxes2d=boxes[rows],
            boxes3d=boxes3d,
            corners=box_corners_camera(boxes3d, R_tilt) if len(rows) else np.zeros((0, 8, 3)),
            color=str(frame.ref.color_path),
            depth=str(frame.ref.depth_path),
            timing=timing,
        )


def detect_folder(
    detector: TorchDetector,
    folder: str | os.PathLike,
    names: Sequence[str] | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> tuple[dict[str, FrameDetections], dict[str, FrameTruth]]:
    """Detections (and, where annotated, ground truth) of the frames of ``folder`` (or ``names``).

    With ``cache_dir`` the proposals of annotated frames come from (and go to) the training
    proposal cache, so periodic validation runs the proposal stage once per frame.
    """
    intrinsics = read_folder_intrinsics(folder)
    refs = list_frames(folder)
    if names is not None:
        wanted = set(names)
        refs = [r for r in refs if r.name in wanted]
    detections, truth = {}, {}
    for ref in refs:
        frame = read_frame(ref, intrinsics)
        gt = read_ground_truth(ref)
        segments = None
        if gt is not None and cache_dir is not None:
            front = cached_front_end(ref, gt, intrinsics, detector.config.proposals, cache_dir)
            segments = Segments(front.proposal_boxes, front.proposal_centers, front.proposal_valid)
        detections[ref.name] = detector.detect(frame, segments)
        if gt is not None and frame.R_tilt is not None:
            truth[ref.name] = FrameTruth(gt.class_ids, gt.boxes3d, frame.R_tilt)
    return detections, truth


def validate(
    detector: TorchDetector,
    folder: str | os.PathLike,
    max_frames: int = 0,
    cache_dir: str | os.PathLike | None = None,
) -> EvalResult:
    """The paper's mAP (a3d.runtime.evaluation) on the annotated frames of ``folder``."""
    names = [r.name for r in list_frames(folder) if r.gt_path is not None]
    if max_frames > 0:
        names = names[:max_frames]
    detections, truth = detect_folder(detector, folder, names, cache_dir)
    return evaluate(truth, {k: v for k, v in detections.items() if k in truth}, EvalConfig())
