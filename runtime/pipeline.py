"""The per-frame detection pipeline of the edge runtime: a frame in memory -> its detections.

The core takes a ``Frame`` (a3d.runtime.structures.frame: colour, metric depth, intrinsics,
optional R_tilt and precomputed proposals), whatever source it came from; reading files is a
frame source's job (a3d.runtime.sources). Three stages, so that the CPU front end of one frame
can overlap the network call of another:

1. ``prepare`` (numpy + OpenCV): bring a frame larger than the networks' working size down to it
   (frontend.working_size; its detections' 2D boxes go back to its own pixels), fill the depth
   holes, choose R_tilt (the frame's own, the estimate from the depth, or a fallback the line
   names: frontend.gravity.choose_gravity),
   compute segment proposals (or use the frame's precomputed ones), lift them
   to initial 3D centres (proposals without any depth are dropped); with a 2D detector, its boxes
   (computed on a thread of their own meanwhile) lifted and added as RoIs; and build the network
   inputs: the trunk images at the model's
   ``input_scale`` and the proposal and context RoIs in the resized image's pixel coordinates;
2. ``infer``: one ONNX Runtime call per frame (both trunks once, the head over all RoIs at once);
3. ``finish``: the model's score calibration (postprocess.score_calibration), per-class top-k
   and 2D NMS (with a 2D detector, its boxes merged in; with an image classifier, its second
   opinion on the best own detections: postprocess.fuse), class-specific 3D boxes and amodal 2D boxes
   (a3d.runtime.postprocess.select) bounded to boxes that can exist (postprocess.box_limits),
   with a 2D detector the 3D boxes turned square to the walls the depth shows
   (postprocess.wall_axes), doors slid onto the surface it shows (postprocess.depth_fit), what
   stands on the floor reaching down to it (postprocess.floor_contact) and the scores moved by
   how much of the depth in each 2D box its 3D box holds (postprocess.depth_support), corners,
   and the frame's detections line, with its gravity source and notes.

Every stage adds its wall time (seconds) to the frame's ``timing``: read, depth_fill, gravity,
proposals, lifting, detector2d, network_input, network, classifier2d, postprocess, and total (their sum).

``detect_frames`` runs the frames of a source (``FrameLoader``s, read where the "read" stage is
timed) and never stops at a bad one: each frame comes back with its result or a one-line problem
("ORIGIN: what is wrong"). It takes the source lazily, one frame ahead at most, so a live source
is never drained in advance. With ``overlap`` one background thread
prepares frame i + 1 while the calling thread runs the network on frame i; the caller then gives
the network one thread fewer so that the cores are not oversubscribed. That pays only where the
front end takes longer than the network (a small model); with the paper's VGG16 on 2 cores it
doubles the network's time. ``detect_frames_auto`` times a frame sequentially and overlaps the
rest only where ``overlap_pays`` (a3d-run's default, ``--overlap auto``).
"""

from __future__ import annotations

import itertools
import logging
import os
import time
import typing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, Protocol

import cv2
import numpy as np

from a3d.runtime.clock import Clock
from a3d.runtime.errors import InputError, ModelError
from a3d.runtime.frontend.box_pixels import class_reach, lift_boxes
from a3d.runtime.frontend.depth import fill_depth_info
from a3d.runtime.frontend.frame_proposals import frame_proposals
from a3d.runtime.frontend.gravity import choose_gravity
from a3d.runtime.frontend.lifting import lift
from a3d.runtime.frontend.proposals import ProposalConfig, Proposals, live_proposals
from a3d.runtime.frontend.working_size import WORKING_SIDE, WorkingFrame, working_frame
from a3d.runtime.io.detections_io import FrameDetections
from a3d.runtime.network.network_input import frame_network_inputs
from a3d.runtime.postprocess.box_limits import bound_boxes, near_range
from a3d.runtime.postprocess.depth_fit import fit_to_depth
from a3d.runtime.postprocess.depth_support import rescored, sample_depth
from a3d.runtime.postprocess.floor_contact import NO_FLOOR, frame_floor, stand_on_floor
from a3d.runtime.postprocess.fuse import (
    NETWORK,
    Picked,
    detector_picks,
    merge,
    second_opinion,
    second_opinion_rows,
)
from a3d.runtime.postprocess.hold_depth import hold_depth
from a3d.runtime.postprocess.long_axis import along_depth
from a3d.runtime.postprocess.score_calibration import ScoreCalibration
from a3d.runtime.postprocess.select import decode_detections, select_detections
from a3d.runtime.postprocess.wall_axes import NO_WALLS, square_to_walls, wall_direction
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.proposals_file import PrecomputedProposals
from a3d.runtime.sources.wording import option
from a3d.runtime.structures.boxes import BOX_DIM
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import box_corners_camera

if TYPE_CHECKING:
    from a3d.runtime.detector2d import Detections2D
    from a3d.runtime.network.model import ModelMetadata

ProposalSource = Literal["auto", "compute", "precomputed"]
PROPOSAL_SOURCES: tuple[str, ...] = typing.get_args(ProposalSource)
FrontEnd = Literal["model", "live"]
FRONT_ENDS: tuple[str, ...] = typing.get_args(FrontEnd)
MOSTLY_MISSING = 0.5  # a frame with more of its depth missing than this says so in its line
logger = logging.getLogger(__name__)
PROBE_FRAMES = 3  # overlapped frames timed by --overlap auto before it keeps overlapping
OVERLAP_NOISE = 1.05  # "never slower": within 5 % of sequential, the spread of runs on a quiet machine
_detector_threads: dict[int, ThreadPoolExecutor] = {}  # per process id: see _detector_thread
STAGES = (
    "read", "depth_fill", "gravity", "proposals", "lifting", "detector2d", "network_input", "network",
    "classifier2d", "postprocess",
)  # fmt: skip
FRONT_END_STAGES = STAGES[: STAGES.index("network")]  # what ``load_and_prepare`` times


class BoxDetector(Protocol):
    """What the pipeline needs of a 2D detector: a3d.runtime.detector2d.Detector2D."""

    name: str

    @property
    def classes(self) -> np.ndarray: ...

    def detect(self, color_rgb: np.ndarray) -> Detections2D: ...


class ImageClassifier(Protocol):
    """What the pipeline needs of an image classifier: a3d.runtime.classifier2d.Classifier2D."""

    name: str

    @property
    def classes(self) -> np.ndarray: ...

    def classify(self, color_rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray: ...


class NetworkRunner(Protocol):
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
    post-processing; ``proposal_source``: "auto" uses a frame's precomputed proposals where it
    has them, "compute" always runs a3d.runtime.frontend.proposals, "precomputed" requires them;
    ``proposals.max_proposals`` caps computed and precomputed proposals alike (the first ones kept);
    ``front_end`` "model" computes proposals with the model's settings, "live" with
    a3d.runtime.frontend.proposals.live_proposals (about 4x faster and at most 500, for cameras);
    an explicit ``max_proposals`` overrides either. ``score_calibration`` maps the network's class
    scores before top-k, threshold and NMS (the model's own, a3d.runtime.postprocess.score_calibration;
    None: the softmax as it is). ``detector``: a 2D detector whose boxes join the RoIs
    (a3d.runtime.postprocess.fuse), None for a3d's own proposals alone. ``classifier``: an image
    classifier whose view of the best own detections of the classes ``detector`` does not know
    rescores them (postprocess.fuse.second_opinion), None for none. ``working_side``: a frame whose
    longer side is over it is brought down to it first (frontend.working_size), None or 0: every
    frame as it comes.
    """

    mean_sizes: np.ndarray
    proposals: ProposalConfig = field(default_factory=ProposalConfig)
    proposal_source: ProposalSource = "auto"
    input_scale: float = 1.0
    context_scale: float = 1.5
    depth_truncation_m: float = 10.0
    top_k: int = 100
    nms_iou: float = 0.3
    min_score: float = 0.0
    score_calibration: ScoreCalibration | None = None
    detector: BoxDetector | None = None
    classifier: ImageClassifier | None = None
    working_side: int | None = WORKING_SIDE

    @classmethod
    def from_metadata(
        cls,
        metadata: ModelMetadata,
        *,
        proposal_source: ProposalSource = "auto",
        max_proposals: int | None = None,
        min_score: float | None = None,
        front_end: FrontEnd = "model",
        raw_scores: bool = False,
    ) -> PipelineConfig:
        """The model's settings (a3d.runtime.network.model.ModelMetadata, checked by DetectorModel.load),
        with the command line's overrides (``raw_scores``: leave the model's score calibration off)."""
        if front_end not in FRONT_ENDS:
            raise ValueError(f"front_end: expected one of {', '.join(FRONT_ENDS)}, got {front_end!r}")
        proposals = live_proposals(metadata.proposals) if front_end == "live" else metadata.proposals
        if max_proposals is not None:
            proposals = replace(proposals, max_proposals=int(max_proposals))
        return cls(
            mean_sizes=np.asarray(metadata.mean_sizes, np.float64),
            proposals=proposals,
            proposal_source=proposal_source,
            input_scale=float(metadata.input_scale),
            context_scale=float(metadata.context_scale),
            depth_truncation_m=float(metadata.depth_truncation_m),
            top_k=int(metadata.top_k),
            nms_iou=float(metadata.nms_iou),
            min_score=float(metadata.min_score if min_score is None else min_score),
            score_calibration=None if raw_scores else metadata.score_calibration,
        )


# ----------------------------------------------------------------------------- stages


@dataclass(eq=False)
class PreparedFrame:
    """A frame after the CPU front end, ready for the network.

    ``frame`` as it came and ``working`` the same at the working size (frontend.working_size), which
    everything after is computed on: ``boxes`` (N, 4) proposal boxes in its pixels and ``centers``
    (N, 3) their lifted centres (liftable proposals only); ``color_input`` / ``depth_input`` (1, 3,
    h, w) float32 trunk inputs; ``rois`` / ``context_rois`` (N, 4) float32 in the trunk image's
    pixels. ``found``: the 2D detector's liftable boxes, the last ``len(found.boxes)`` rows of ``boxes``.
    """

    frame: Frame
    working: WorkingFrame
    R_tilt: np.ndarray
    boxes: np.ndarray
    centers: np.ndarray
    color_input: np.ndarray
    depth_input: np.ndarray
    rois: np.ndarray
    context_rois: np.ndarray
    timing: dict[str, float]
    gravity: str = ""
    notes: list[str] = field(default_factory=list)
    found: Detections2D | None = None
    detector: str = ""

    @property
    def work(self) -> Frame:
        """The frame at the working size."""
        return self.working.frame

    @property
    def native_boxes(self) -> np.ndarray:
        """``boxes`` in the pixels of ``frame`` as it came (what a viewer draws on it)."""
        return self.working.to_native(self.boxes)

    @property
    def own_rows(self) -> int:
        """How many RoIs are a3d's own proposals (the first ones)."""
        return len(self.boxes) - (0 if self.found is None else len(self.found.boxes))


@dataclass(eq=False)
class NetworkOutput:
    """Per RoI: softmax (N, 20), raw 3D deltas (N, 20, 7), raw amodal 2D deltas (N, 20, 4)."""

    probs: np.ndarray
    deltas3d: np.ndarray
    deltas2d: np.ndarray


def prepare(frame: Frame, config: PipelineConfig, timing: dict[str, float] | None = None) -> PreparedFrame:
    """Stage 1: everything before the network (see the module docstring); ``timing`` may already
    hold the frame's read time."""
    timing = {} if timing is None else timing
    clock = Clock(timing)
    notes: list[str] = [frame.pose_note] if frame.pose_note else []
    side, (height, width) = config.working_side, frame.image_size
    own_proposals = frame.proposals is not None and config.proposal_source != "compute"
    if side and max(height, width) > side and own_proposals:  # cut for its own size
        notes.append(f"{width} x {height} kept for its precomputed proposals: the network works best at "
                     f"{side} across (--proposals compute brings it there)")  # fmt: skip
        side = None
    native, working = frame, working_frame(frame, side)
    frame = working.frame
    clock.lap("read")  # bringing it to the working size is part of reading it
    boxes_of = config.detector
    detecting = None if boxes_of is None else _detector_thread().submit(_detect, boxes_of, frame.color)
    fill = fill_depth_info(frame.depth)
    filled = fill.depth
    if fill.hole_fraction > MOSTLY_MISSING:
        notes.append(f"depth mostly missing: {fill.hole_fraction:.0%} of the pixels have none")
    clock.lap("depth_fill")
    gravity = choose_gravity(frame.depth, filled, frame.intrinsics, frame.R_tilt)
    if gravity.is_fallback:
        logger.warning("%s: gravity %s", frame.origin or frame.name, gravity.source)
    clock.lap("gravity")
    segments, boxes = _proposals(frame, filled, config, notes)
    clock.lap("proposals")
    centers = np.zeros((0, 3))
    if len(boxes):
        lifted = lift(segments, frame.depth, filled, frame.intrinsics)
        boxes, centers = boxes[lifted.valid], lifted.centers[lifted.valid]
        if not len(boxes):
            notes.append("no proposals: none has depth to lift it")
    clock.lap("lifting")
    found = None if detecting is None else _detector_boxes(detecting, config, notes)
    if found is not None and len(found.boxes):
        reach = class_reach(found.candidates, config.mean_sizes)
        lifted = lift_boxes(found.boxes, reach, frame.depth, filled, frame.intrinsics)
        found = _subset(found, lifted.valid)
        boxes = np.concatenate([boxes, found.boxes])
        centers = np.concatenate([centers, lifted.centers[lifted.valid]])
    clock.lap("detector2d")
    color, depth, rois, context_rois = frame_network_inputs(
        frame.color, filled, boxes, config.input_scale, config.depth_truncation_m, config.context_scale
    )
    clock.lap("network_input")
    R_tilt = np.asarray(gravity.R_tilt, np.float64)
    inputs = (color[None], depth[None], rois, context_rois)
    detector = "" if config.detector is None else config.detector.name
    return PreparedFrame(
        native, working, R_tilt, boxes, centers, *inputs, timing, gravity.source, notes, found, detector
    )


def _detector_thread() -> ThreadPoolExecutor:
    """The thread the 2D detector runs on, beside the depth fill, the proposals and the lifting (it
    needs the colour alone; its stage, detector2d, is what the frame still waits for it after
    them): one per process, since a forked child has none of its parent's threads."""
    pid = os.getpid()
    if pid not in _detector_threads:
        _detector_threads[pid] = ThreadPoolExecutor(max_workers=1, thread_name_prefix="a3d-detector2d")
    return _detector_threads[pid]


def _detect(detector: BoxDetector, color_bgr: np.ndarray) -> Detections2D:
    """The 2D detector on a frame's colour (BGR, as frames hold it; the detector takes RGB)."""
    return detector.detect(np.ascontiguousarray(color_bgr[..., ::-1]))


def _detector_boxes(
    detecting: Future[Detections2D], config: PipelineConfig, notes: list[str]
) -> Detections2D | None:
    """The 2D detector's boxes of the frame, once its thread has them; where it failed, None and a
    note: the frame keeps a3d's own detections."""
    assert config.detector is not None
    try:
        return detecting.result()
    except Exception as error:  # a detector that fails on one frame must not lose the frame
        notes.append(f"2D detector {config.detector.name} failed ({type(error).__name__}: {error}); "
                     "a3d's own detections only")  # fmt: skip
        return None


def _subset(found: Detections2D, keep: np.ndarray) -> Detections2D:
    """The detections ``keep`` (a mask) selects."""
    names = tuple(name for name, kept in zip(found.names, keep, strict=True) if kept)
    return replace(found, boxes=found.boxes[keep], scores=found.scores[keep], class_ids=found.class_ids[keep],
                   candidates=found.candidates[keep], names=names)  # fmt: skip


def load_and_prepare(loader: FrameLoader, config: PipelineConfig) -> PreparedFrame:
    """Read the frame (timed as "read"), then stage 1."""
    timing: dict[str, float] = {}
    clock = Clock(timing)
    frame = loader.load()
    clock.lap("read")
    return prepare(frame, config, timing)


def _proposals(
    frame: Frame, filled: np.ndarray, config: PipelineConfig, notes: list[str]
) -> tuple[Proposals | PrecomputedProposals | np.ndarray, np.ndarray]:
    """(segments in a form ``lift`` takes, boxes (N, 4) float64), at most ``max_proposals``;
    ``notes`` learns when there are none. The cap cutting the list is the configured top N, normal
    operation, so it is only logged (debug)."""
    if config.proposal_source == "precomputed" and frame.proposals is None:
        raise InputError(f"{frame.origin}: no precomputed proposals ({option('proposals_precomputed')})")
    precomputed = None if config.proposal_source == "compute" else frame.proposals
    segments, boxes = frame_proposals(frame.color, filled, frame.intrinsics, config.proposals, precomputed)
    if precomputed is None and not len(boxes):
        notes.append("no proposals: the segmentation found no candidate object")
    elif precomputed is not None and not len(precomputed):
        notes.append("no proposals: the precomputed list is empty")
    elif len(boxes) >= config.proposals.max_proposals:
        logger.debug("%s: proposals capped at %d", frame.origin, config.proposals.max_proposals)
    return segments, boxes


def infer(model: NetworkRunner, prepared: PreparedFrame) -> NetworkOutput:
    """Stage 2: one model call over all RoIs of the frame (skipped when there are none)."""
    clock = Clock(prepared.timing)
    n, c = len(prepared.rois), NUM_OUTPUTS
    shapes = {"class_probs": (n, c), "deltas3d": (n, c, BOX_DIM), "deltas2d": (n, c, 4)}
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
    clock = Clock(prepared.timing)
    class_scores = out.probs[:, 1:]
    if config.score_calibration is not None:
        class_scores = config.score_calibration.apply(class_scores)
    picked = _picked(prepared, class_scores, config)
    if config.classifier is not None:
        clock.lap("postprocess")
        picked = _second_opinion(prepared, picked, config)
        clock.lap("classifier2d")
    rows, class_idx, scores = picked.rows, picked.class_idx, picked.scores
    boxes3d, amodal = decode_detections(
        rows,
        class_idx,
        prepared.centers,
        config.mean_sizes,
        prepared.boxes,
        out.deltas3d,
        out.deltas2d,
        prepared.work.image_size,
    )
    bounded = bound_boxes(boxes3d, class_idx, near_range(prepared.work.depth))
    boxes3d, sources = bounded.boxes3d, picked.sources
    depth_notes: list[str] = []
    if prepared.found is not None and len(rows):  # steps 6, 7, 8, 5, 10, 9 (docs/real-rooms.md)
        frame, boxes2d = prepared.work, prepared.boxes[rows]
        direction = wall_direction(frame.depth, frame.intrinsics, prepared.R_tilt)
        if direction is None:
            depth_notes.append(NO_WALLS)
        else:
            boxes3d = square_to_walls(boxes3d, direction)
        sampled = sample_depth(frame.depth, frame.intrinsics, prepared.R_tilt)  # once, for all three
        boxes3d = fit_to_depth(sampled, boxes2d, boxes3d, class_idx, scores)
        plane = frame_floor(sampled)
        if plane is None:
            depth_notes.append(NO_FLOOR)
        else:
            boxes3d = stand_on_floor(boxes3d, class_idx, plane, prepared.R_tilt)
        scores = rescored(scores, sampled, boxes2d, boxes3d)
        boxes3d = along_depth(sampled, boxes2d, boxes3d, class_idx, scores, plane)  # step 10, after 5
        boxes3d = hold_depth(sampled, boxes2d, boxes3d, scores, plane)  # step 9, after 5: moves no score
        order = np.argsort(-scores, kind="stable")
        rows, class_idx, boxes3d, amodal = (a[order] for a in (rows, class_idx, boxes3d, amodal))
        scores, bounded, sources = scores[order], bounded.reordered(order), tuple(sources[i] for i in order)
    corners = box_corners_camera(boxes3d, prepared.R_tilt) if len(rows) else np.zeros((0, 8, 3))
    clock.lap("postprocess")
    timing = prepared.timing
    timing["total"] = sum(timing[stage] for stage in STAGES if stage in timing)
    frame, working = prepared.frame, prepared.working
    return FrameDetections(
        frame=frame.name,
        R_tilt=prepared.R_tilt,
        class_ids=class_idx,
        scores=scores,
        boxes2d=working.to_native(prepared.boxes[rows]),
        boxes3d=boxes3d,
        corners=corners,
        color=frame.color_file,
        depth=frame.depth_file,
        timing=dict(timing),
        boxes2d_amodal=working.to_native(amodal),
        gravity=prepared.gravity,
        notes=(*prepared.notes, *depth_notes, *bounded.notes(scores)),
        intrinsics=frame.intrinsics,
        pose=frame.pose,
        sources=sources if prepared.detector or config.classifier is not None else None,
    )


def _picked(prepared: PreparedFrame, class_scores: np.ndarray, config: PipelineConfig) -> Picked:
    """The frame's detections: a3d's own (top-k, threshold, NMS) and, with a detector, its boxes,
    merged (a3d.runtime.postprocess.fuse)."""
    n = prepared.own_rows
    rows, class_idx, scores = select_detections(
        class_scores[:n], prepared.boxes[:n], config.top_k, config.min_score, config.nms_iou
    )
    own = Picked(rows, class_idx, scores, (NETWORK,) * len(rows))
    found = prepared.found
    if found is None or not len(found.boxes):
        return own
    picks = detector_picks(class_scores, prepared.boxes, n, found.scores, found.candidates, prepared.detector)
    alive = picks.scores >= config.min_score
    picks = Picked(picks.rows[alive], picks.class_idx[alive], picks.scores[alive],
                   tuple(s for s, a in zip(picks.sources, alive, strict=True) if a))  # fmt: skip
    return merge(own, picks, prepared.boxes, found.scores[picks.rows - n])


def _second_opinion(prepared: PreparedFrame, picked: Picked, config: PipelineConfig) -> Picked:
    """``picked`` with the classifier's second opinion on its best own detections of the classes
    the classifier knows and the 2D detector does not; where it fails, a note and ``picked``."""
    assert config.classifier is not None
    classes = config.classifier.classes
    if config.detector is not None:
        classes = classes & ~config.detector.classes
    chosen = second_opinion_rows(picked, classes)
    if not len(chosen):
        return picked
    color = np.ascontiguousarray(prepared.work.color[..., ::-1])
    try:
        probs = config.classifier.classify(color, prepared.boxes[picked.rows[chosen]])
    except Exception as error:  # a classifier that fails on one frame must not lose the frame
        prepared.notes.append(f"image classifier {config.classifier.name} failed ({type(error).__name__}: "
                              f"{error}); scores without its opinion")  # fmt: skip
        return picked
    return second_opinion(picked, chosen, probs, config.classifier.name)


def detect(frame: Frame, model: NetworkRunner, config: PipelineConfig) -> FrameDetections:
    """All three stages for one frame in memory (raises on a bad frame)."""
    prepared = prepare(frame, config)
    return finish(prepared, infer(model, prepared), config)


# ----------------------------------------------------------------------------- a run over many frames


@dataclass(eq=False)
class FrameOutcome:
    """One frame of a run: its detections and prepared inputs, or the problem that stopped it;
    ``overlapped``: prepared on the background thread during the previous frame's network call."""

    name: str
    origin: str
    detections: FrameDetections | None = None
    prepared: PreparedFrame | None = None
    problem: str = ""
    overlapped: bool = False


def frame_problem(loader: FrameLoader, error: Exception) -> str:
    """A one-line "ORIGIN: problem" for a failed frame: the message as it is when it starts with
    one of the frame's files or its origin (InputError does), else prefixed with the origin."""
    if isinstance(error, ValueError):
        message = str(error)
    else:
        message = f"internal error: {type(error).__name__}: {error}"
    named = any(message.startswith(f"{path}:") for path in (*loader.files, loader.origin))
    return message if named else f"{loader.origin}: {message}"


def detect_frames(
    loaders: Iterable[FrameLoader],
    model: NetworkRunner,
    config: PipelineConfig,
    *,
    overlap: bool = False,
) -> Iterator[FrameOutcome]:
    """Run frames in order; a bad frame yields its problem and the run goes on.

    With ``overlap``, frame i + 1 is loaded and prepared on one background thread during frame
    i's network call and post-processing (at most two frames in flight).
    """
    if not overlap:
        for loader in loaders:
            yield _run_one(loader, lambda item=loader: load_and_prepare(item, config), model, config)
        return
    items = iter(loaders)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="a3d-prepare") as pool:
        current = next(items, None)
        pending = None if current is None else pool.submit(load_and_prepare, current, config)
        first = True
        while current is not None and pending is not None:
            following = next(items, None)
            ready = pending
            pending = None if following is None else pool.submit(load_and_prepare, following, config)
            yield replace(_run_one(current, ready.result, model, config), overlapped=not first)
            current, first = following, False


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
    loaders: Iterable[FrameLoader],
    model: NetworkRunner,
    config: PipelineConfig,
    *,
    threads: int,
    narrow: Callable[[int], NetworkRunner],
    probe: int = PROBE_FRAMES,
) -> Iterator[FrameOutcome]:
    """``detect_frames`` that chooses overlap where it is faster: frames run sequentially on
    ``model`` (``threads`` threads) until one after the first (a warm-up) has its timing; the rest
    then overlap, with the network on ``narrow(threads - 1)``, where ``overlap_pays`` for it,
    else go on sequentially. The prediction can be wrong (a network that scales badly to fewer
    threads, a machine busy elsewhere), so the overlapped frames are timed too: where ``probe`` of
    them came slower than the timed sequential frame, the run goes back to sequential for good
    (with a warning). The source is taken lazily as by ``detect_frames``; the outcomes say which
    way each frame ran (``overlapped``)."""
    items = iter(loaders)
    for i, loader in enumerate(items):
        began = time.perf_counter()
        outcome = _run_one(loader, lambda item=loader: load_and_prepare(item, config), model, config)
        yield outcome
        if i == 0 or outcome.detections is None:
            continue
        sequential = time.perf_counter() - began  # the frame and the caller's own work on it
        following = next(items, None)  # a live source's next frame, which the run needs next anyway
        if following is None:
            return
        rest = itertools.chain([following], items)
        if overlap_pays(outcome.detections.timing, threads):
            opencv_threads = cv2.getNumThreads()  # narrow() may leave OpenCV fewer for the background
            yield from _overlap_while_faster(
                rest, config, model=model, narrow=lambda: narrow(threads - 1), sequential=sequential,
                probe=probe, opencv_threads=opencv_threads,
            )  # fmt: skip
        else:
            yield from detect_frames(rest, model, config)
        return


def _overlap_while_faster(
    items: Iterator[FrameLoader],
    config: PipelineConfig,
    *,
    model: NetworkRunner,
    narrow: Callable[[], NetworkRunner],
    sequential: float,
    probe: int,
    opencv_threads: int,
) -> Iterator[FrameOutcome]:
    """Overlapped frames, as ``detect_frames(overlap=True)`` with the network on ``narrow()``.

    The narrowed session is built on the background thread while the first frame is prepared in
    the foreground (that frame's network runs on ``model``), so the switch costs no frame a
    session's load. After that frame the next ``probe`` are timed and, where their mean period
    exceeds the ``sequential`` one by more than OVERLAP_NOISE, the frame already prepared runs on
    ``model`` and the rest sequentially, with OpenCV's ``opencv_threads`` back."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="a3d-prepare") as pool:
        narrowing = pool.submit(narrow)
        current = next(items, None)
        if current is None:
            return
        following = next(items, None)
        pending = None if following is None else pool.submit(load_and_prepare, following, config)
        yield _run_one(current, lambda: load_and_prepare(current, config), model, config)
        narrowed, current, done, since = narrowing.result(), following, 0, time.perf_counter()
        while current is not None and pending is not None:
            following = next(items, None)
            ready = pending
            pending = None if following is None else pool.submit(load_and_prepare, following, config)
            yield replace(_run_one(current, ready.result, narrowed, config), overlapped=True)
            current, done = following, done + 1
            if done == probe and current is not None and pending is not None:
                period = (time.perf_counter() - since) / probe
                if period > OVERLAP_NOISE * sequential:
                    logger.warning("--overlap auto: overlapped frames took %.0f ms against %.0f ms "
                                   "sequentially; running sequentially from here", 1e3 * period,
                                   1e3 * sequential)  # fmt: skip
                    cv2.setNumThreads(opencv_threads)
                    yield replace(_run_one(current, pending.result, model, config), overlapped=True)
                    yield from detect_frames(items, model, config)
                    return


def _run_one(
    loader: FrameLoader,
    get_prepared: Callable[[], PreparedFrame],
    model: NetworkRunner,
    config: PipelineConfig,
) -> FrameOutcome:
    try:
        prepared = get_prepared()
        detections = finish(prepared, infer(model, prepared), config)
        return FrameOutcome(loader.name, loader.origin, detections, prepared)
    except Exception as error:  # a bad frame must never stop the run; it is reported instead
        return FrameOutcome(loader.name, loader.origin, problem=frame_problem(loader, error))
