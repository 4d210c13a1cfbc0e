"""The per-frame detection pipeline of the edge runtime: frame files -> detections.

Three stages, so that the CPU front end of one frame can overlap the network call of another:

1. ``prepare`` (numpy + OpenCV): read and validate the frame (a3d.runtime.sources.folder), fill the depth
   holes, take R_tilt from ``NAME.meta.json`` or estimate it from the raw depth, compute segment
   proposals (or read ``NAME.proposals.npz``), lift them to initial 3D centres (proposals without
   any depth are dropped), and build the network inputs: the trunk images at the model's
   ``input_scale`` and the proposal and context RoIs in the resized image's pixel coordinates;
2. ``infer``: one ONNX Runtime call per frame (both trunks once, the head over all RoIs at once);
3. ``finish``: per-class top-k and 2D NMS, class-specific 3D boxes and amodal 2D boxes
   (a3d.runtime.postprocess.select), corners, and the frame's detections line.

Every stage adds its wall time (seconds) to the frame's ``timing``: read, depth_fill, gravity,
proposals, lifting, network_input, network, postprocess, and total (their sum).

``detect_frames`` runs a list of frames and never stops at a bad one: each frame comes back with
its result or a one-line problem ("PATH: what is wrong"). With ``overlap`` one background thread
prepares frame i + 1 while the calling thread runs the network on frame i; the caller then gives
the network one thread fewer so that the cores are not oversubscribed. That pays only where the
front end takes longer than the network (a small model); with the paper's VGG16 on 2 cores it
doubles the network's time. ``detect_frames_auto`` times a frame sequentially and overlaps the
rest only where ``overlap_pays`` (a3d-run's default, ``--overlap auto``).
"""

from __future__ import annotations

import dataclasses
import time
import typing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

import numpy as np

from a3d.runtime.errors import InputError, ModelError
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.gravity import estimate_rtilt
from a3d.runtime.frontend.lifting import lift
from a3d.runtime.frontend.proposals import ProposalConfig, Proposals, proposal_config_from_dict, propose
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.network.network_input import network_inputs, scale_boxes
from a3d.runtime.postprocess.select import decode_detections, select_detections
from a3d.runtime.sources.folder import (
    INTRINSICS_FILE,
    Frame,
    FrameRef,
    PrecomputedProposals,
    read_frame,
    read_precomputed_proposals,
)
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.runtime.structures.geometry import Intrinsics, box_corners_camera, context_boxes

ProposalSource = Literal["auto", "compute", "precomputed"]
PROPOSAL_SOURCES: tuple[str, ...] = typing.get_args(ProposalSource)
STAGES = ("read", "depth_fill", "gravity", "proposals", "lifting", "network_input", "network", "postprocess")
FRONT_END_STAGES = STAGES[: STAGES.index("network")]  # what ``prepare`` times


class Detector(Protocol):
    """What the pipeline needs of a model: a3d.runtime.network.model.DetectorModel's ``run``."""

    def run(
        self, color: np.ndarray, depth: np.ndarray, rois: np.ndarray, context_rois: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@dataclass(frozen=True, eq=False)
class PipelineConfig:
    """Everything a frame needs besides its files; built from the model's metadata.

    ``mean_sizes`` (19, 3) class mean [l, w, h] in metres (the initial boxes); ``input_scale``
    the trunk image scale; ``context_scale`` the context box scale about the proposal's centre;
    ``depth_truncation_m`` the depth mapped to 255; ``top_k`` / ``nms_iou`` / ``min_score`` the
    post-processing; ``proposal_source``: "auto" uses ``NAME.proposals.npz`` where a frame has
    one, "compute" always runs a3d.runtime.frontend.proposals, "precomputed" requires the file;
    ``max_proposals`` caps computed and precomputed proposals alike (the first ones are kept).
    """

    mean_sizes: np.ndarray
    proposals: ProposalConfig = field(default_factory=ProposalConfig)
    proposal_source: ProposalSource = "auto"
    max_proposals: int = 2000
    input_scale: float = 1.0
    context_scale: float = 1.5
    depth_truncation_m: float = 10.0
    top_k: int = 100
    nms_iou: float = 0.3
    min_score: float = 0.0

    @classmethod
    def from_metadata(
        cls,
        metadata: Any,
        *,
        proposal_source: ProposalSource = "auto",
        max_proposals: int | None = None,
        min_score: float | None = None,
    ) -> PipelineConfig:
        """The model's settings (a3d.runtime.network.model.ModelMetadata, checked by DetectorModel.load),
        with the command line's overrides."""
        limit = int(metadata.max_proposals if max_proposals is None else max_proposals)
        proposals = proposal_config_from_dict(metadata.proposal_config)
        return cls(
            mean_sizes=np.asarray(metadata.mean_sizes, np.float64),
            proposals=replace(proposals, max_proposals=limit),
            proposal_source=proposal_source,
            max_proposals=limit,
            input_scale=float(metadata.input_scale),
            context_scale=float(metadata.context_scale),
            depth_truncation_m=float(metadata.depth_truncation_m),
            top_k=int(metadata.top_k),
            nms_iou=float(metadata.nms_iou),
            min_score=float(metadata.score_threshold if min_score is None else min_score),
        )


# ----------------------------------------------------------------------------- stages


class _Clock:
    """Lap timer: ``lap(stage)`` adds the seconds since the previous lap to ``timing[stage]``."""

    def __init__(self, timing: dict[str, float]) -> None:
        self.timing = timing
        self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timing[stage] = self.timing.get(stage, 0.0) + (now - self.last)
        self.last = now


@dataclass(eq=False)
class PreparedFrame:
    """A frame after the CPU front end, ready for the network.

    ``boxes`` (N, 4) proposal boxes in native pixels and ``centers`` (N, 3) their lifted centres
    (liftable proposals only); ``color_input`` / ``depth_input`` (1, 3, h, w) float32 trunk
    inputs; ``rois`` / ``context_rois`` (N, 4) float32 in the resized image's pixels.
    """

    frame: Frame
    R_tilt: np.ndarray
    boxes: np.ndarray
    centers: np.ndarray
    color_input: np.ndarray
    depth_input: np.ndarray
    rois: np.ndarray
    context_rois: np.ndarray
    timing: dict[str, float]


@dataclass(eq=False)
class NetworkOutput:
    """Per RoI: softmax (N, 20), raw 3D deltas (N, 20, 7), raw amodal 2D deltas (N, 20, 4)."""

    probs: np.ndarray
    deltas3d: np.ndarray
    deltas2d: np.ndarray


def prepare(ref: FrameRef, folder_intrinsics: Intrinsics | None, config: PipelineConfig) -> PreparedFrame:
    """Stage 1: everything before the network (see the module docstring)."""
    timing: dict[str, float] = {}
    clock = _Clock(timing)
    frame = read_frame(ref, folder_intrinsics)
    clock.lap("read")
    filled = fill_depth(frame.depth)
    clock.lap("depth_fill")
    R_tilt = frame.R_tilt if frame.R_tilt is not None else estimate_rtilt(frame.depth, frame.intrinsics)
    clock.lap("gravity")
    segments, boxes = _proposals(frame, filled, config)
    clock.lap("proposals")
    centers = np.zeros((0, 3))
    if len(boxes):
        lifted = lift(segments, frame.depth, filled, frame.intrinsics)
        boxes, centers = boxes[lifted.valid], lifted.centers[lifted.valid]
    clock.lap("lifting")
    scale, truncation = config.input_scale, config.depth_truncation_m
    color, depth, (sx, sy) = network_inputs(frame.color, filled, scale, truncation)
    context = context_boxes(boxes, frame.image_size, config.context_scale)
    rois = scale_boxes(boxes, sx, sy).astype(np.float32)
    context_rois = scale_boxes(context, sx, sy).astype(np.float32)
    clock.lap("network_input")
    R_tilt = np.asarray(R_tilt, np.float64)
    return PreparedFrame(frame, R_tilt, boxes, centers, color[None], depth[None], rois, context_rois, timing)


def _proposals(
    frame: Frame, filled: np.ndarray, config: PipelineConfig
) -> tuple[Proposals | PrecomputedProposals | np.ndarray, np.ndarray]:
    """(segments in a form ``lift`` takes, boxes (N, 4) float64), at most ``max_proposals``."""
    path = frame.ref.proposals_path
    if config.proposal_source == "precomputed" and path is None:
        raise InputError(f"{frame.ref.color_path}: no {frame.name}.proposals.npz (--proposals precomputed)")
    if path is None or config.proposal_source == "compute":
        computed = propose(frame.color, filled, frame.intrinsics, config.proposals)
        return computed, np.asarray(computed.boxes, np.float64)
    pre = read_precomputed_proposals(path, frame.image_size)
    n = min(len(pre), config.max_proposals)
    boxes = np.asarray(pre.boxes[:n], np.float64)
    if pre.packed_masks is not None:
        masks = np.unpackbits(pre.packed_masks[:n], axis=-1, count=frame.image_size[1]).view(bool)
        return masks, boxes
    assert pre.indptr is not None and pre.indices is not None
    end = int(pre.indptr[n])
    return replace(pre, boxes=pre.boxes[:n], indptr=pre.indptr[: n + 1], indices=pre.indices[:end]), boxes


def infer(model: Detector, prepared: PreparedFrame) -> NetworkOutput:
    """Stage 2: one model call over all RoIs of the frame (skipped when there are none)."""
    clock = _Clock(prepared.timing)
    n, c = len(prepared.rois), NUM_OUTPUTS
    shapes = {"class_probs": (n, c), "deltas3d": (n, c, 7), "deltas2d": (n, c, 4)}
    if n == 0:
        outputs = [np.zeros(shape) for shape in shapes.values()]
    else:
        p = prepared
        outputs = [np.asarray(a) for a in model.run(p.color_input, p.depth_input, p.rois, p.context_rois)]
        for (name, shape), value in zip(shapes.items(), outputs, strict=True):
            if value.shape != shape:
                raise ModelError(f"model output {name} has shape {value.shape}, expected {shape}")
        if not np.isfinite(outputs[0]).all():
            raise ModelError("model output class_probs is not finite")
    clock.lap("network")
    return NetworkOutput(*outputs)


def finish(prepared: PreparedFrame, out: NetworkOutput, config: PipelineConfig) -> FrameDetections:
    """Stage 3: selection, decoding and corners; the frame's detections line."""
    clock = _Clock(prepared.timing)
    rows, class_idx, scores = select_detections(
        out.probs[:, 1:], prepared.boxes, config.top_k, config.min_score, config.nms_iou
    )
    boxes3d, amodal = decode_detections(
        rows,
        class_idx,
        prepared.centers,
        config.mean_sizes,
        prepared.boxes,
        out.deltas3d,
        out.deltas2d,
        prepared.frame.image_size,
    )
    corners = box_corners_camera(boxes3d, prepared.R_tilt) if len(rows) else np.zeros((0, 8, 3))
    clock.lap("postprocess")
    timing = prepared.timing
    timing["total"] = sum(timing[stage] for stage in STAGES if stage in timing)
    ref = prepared.frame.ref
    return FrameDetections(
        frame=prepared.frame.name,
        R_tilt=prepared.R_tilt,
        class_ids=class_idx,
        scores=scores,
        boxes2d=prepared.boxes[rows],
        boxes3d=boxes3d,
        corners=corners,
        color=str(ref.color_path),
        depth=str(ref.depth_path),
        timing=dict(timing),
        boxes2d_amodal=amodal,
    )


def detect(
    ref: FrameRef, model: Detector, config: PipelineConfig, folder_intrinsics: Intrinsics | None
) -> FrameDetections:
    """All three stages for one frame (raises on a bad frame)."""
    prepared = prepare(ref, folder_intrinsics, config)
    return finish(prepared, infer(model, prepared), config)


# ----------------------------------------------------------------------------- a run over many frames


@dataclass(eq=False)
class FrameOutcome:
    """One frame of a run: its detections and prepared inputs, or the problem that stopped it;
    ``overlapped``: prepared on the background thread during the previous frame's network call."""

    ref: FrameRef
    detections: FrameDetections | None = None
    prepared: PreparedFrame | None = None
    problem: str = ""
    overlapped: bool = False


def frame_problem(ref: FrameRef, error: Exception) -> str:
    """A one-line "PATH: problem" for a failed frame: the message as it is when it starts with one
    of the frame's files (InputError does), else prefixed with the colour file."""
    if isinstance(error, ValueError):
        message = str(error)
    else:
        message = f"internal error: {type(error).__name__}: {error}"
    files = [getattr(ref, f.name) for f in dataclasses.fields(ref) if f.name.endswith("_path")]
    files.append(ref.color_path.parent / INTRINSICS_FILE)
    named = any(message.startswith(f"{path}:") for path in files if path is not None)
    return message if named else f"{ref.color_path}: {message}"


def detect_frames(
    refs: Iterable[FrameRef],
    model: Detector,
    config: PipelineConfig,
    folder_intrinsics: Intrinsics | None,
    *,
    overlap: bool = False,
) -> Iterator[FrameOutcome]:
    """Run frames in order; a bad frame yields its problem and the run goes on.

    With ``overlap``, frame i + 1 is prepared on one background thread during frame i's network
    call and post-processing (at most two frames in flight).
    """
    refs = list(refs)
    if not overlap:
        for ref in refs:
            yield _run_one(ref, lambda r=ref: prepare(r, folder_intrinsics, config), model, config)
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="a3d-prepare") as pool:
        pending: Future | None = None
        for i, ref in enumerate(refs):
            current = pending or pool.submit(prepare, ref, folder_intrinsics, config)
            following = refs[i + 1] if i + 1 < len(refs) else None
            pending = pool.submit(prepare, following, folder_intrinsics, config) if following else None
            yield replace(_run_one(ref, current.result, model, config), overlapped=i > 0)


def overlap_pays(timing: dict[str, float], threads: int, margin: float = 0.9) -> bool:
    """Whether frames like this one (its ``timing``, run sequentially on ``threads`` threads) come
    faster with the next frame prepared on a background thread and the network on one thread fewer.

    Predicted overlapped period: max(network x threads / (threads - 1) + postprocess, front end),
    against front end + network + postprocess sequentially; overlap only where that is below
    ``margin`` x sequential. The network is assumed to scale linearly with threads (it scales
    less, so the real overlapped period is shorter: the choice errs towards sequential), and the
    caller's own per-frame work (writing, logging) is left out of both (it only adds to the gain).
    With a network much longer than the front end (the paper's VGG16 on 2 cores) overlap would
    double the network's time for a small hidden front end; with a small network it hides the
    network behind the front end.
    """
    if threads < 2:
        return False
    front = sum(timing.get(stage, 0.0) for stage in FRONT_END_STAGES)
    network, post = timing.get("network", 0.0), timing.get("postprocess", 0.0)
    overlapped = max(network * threads / (threads - 1) + post, front)
    return overlapped < margin * (front + network + post)


def detect_frames_auto(
    refs: Iterable[FrameRef],
    model: Detector,
    config: PipelineConfig,
    folder_intrinsics: Intrinsics | None,
    *,
    threads: int,
    narrow: Callable[[int], Detector],
) -> Iterator[FrameOutcome]:
    """``detect_frames`` that chooses overlap where it is faster: frames run sequentially on
    ``model`` (``threads`` threads) until one after the first (a warm-up) has its timing; the rest
    then overlap, with the network on ``narrow(threads - 1)``, where ``overlap_pays`` for it,
    else go on sequentially. The outcomes say which way each frame ran (``overlapped``)."""
    refs = list(refs)
    for i, ref in enumerate(refs):
        outcome = _run_one(ref, lambda r=ref: prepare(r, folder_intrinsics, config), model, config)
        yield outcome
        if i == 0 or outcome.detections is None or i + 1 == len(refs):
            continue
        rest = refs[i + 1 :]
        if overlap_pays(outcome.detections.timing, threads):
            yield from detect_frames(rest, narrow(threads - 1), config, folder_intrinsics, overlap=True)
        else:
            yield from detect_frames(rest, model, config, folder_intrinsics)
        return


def _run_one(
    ref: FrameRef, get_prepared: Callable[[], PreparedFrame], model: Detector, config: PipelineConfig
) -> FrameOutcome:
    try:
        prepared = get_prepared()
        return FrameOutcome(ref, finish(prepared, infer(model, prepared), config), prepared)
    except Exception as error:  # a bad frame must never stop the folder; it is reported instead
        return FrameOutcome(ref, problem=frame_problem(ref, error))
