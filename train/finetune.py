"""a3d-finetune's work: a model fine-tuned on a user's labelled recordings within a time budget.

1. the recordings are read and split (a3d.train.finetune_data: whole stretches at the end held
   back), synthetic frames of the bundled model's world made (or taken) to mix in, so the classes
   the user's rooms lack are not forgotten;
2. the base model is scored on the held-back frames (the "before"): its network alone, and the
   pipeline a3d-run runs with it (its 2D detector and the steps after the network), where it has
   a detector;
3. its weights are read back from its file (a3d.export.read_back), the training frames' RoI
   database built (a3d.train.roidb, cached in the work folder), the heads put in terms of those
   frames' target statistics and saved as the checkpoint a3d-train fine-tunes (``solver.init``);
4. a3d-train's own loop (a3d.train.loop.train) runs for what is left of the budget less the
   export's share (``solver.minutes``): the colour trunk frozen and its features cached, the
   depth trunk's first ten convolutions frozen (docs/training.md "Your own room"), every
   BatchNorm's statistics fixed (they were folded into the weights), no dropout (the base trained
   with it, but its BatchNorms, folded now, normalised the dropped-out activations; with them fixed,
   dropout trains fc7 and the heads on activations the exported network never sees: with it the
   fine-tune lost 0.5 to 0.7 points on other rooms' frames, without it it gains 0.3 to 0.6),
   bfloat16 where the CPU has it;
   Ctrl-C stops it with the last iteration's checkpoint, which is exported as any other;
5. a3d-export's steps (a3d.export.build.export): int8 calibrated on training frames, verified and
   its scores calibrated on the held-back frames, which scores the network's "after";
6. the model card: ``provenance["finetune"]`` (base model, the user's data, the recipe, mAP@0.25
   on the held-back frames before and after: the network's, and the pipeline's, scored again with
   the new file as a3d-run runs it), the base pipeline's 2D detector named in the metadata (the
   detector is not fine-tuned; a3d-run runs the new network with it), the file written atomically.
   Where the fine-tuned pipeline scores lower there than the base's, the run says so: the base
   stays the better choice for that room.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from a3d.export.base import MIN_OPSET
from a3d.export.build import export
from a3d.export.onnx_export import save_model
from a3d.export.read_back import ReadBack, normalise_heads, read_back
from a3d.export.score_calibration import IOU, score_on
from a3d.runtime.detector import Detector
from a3d.runtime.errors import InputError
from a3d.runtime.evaluation.metric import EvalResult
from a3d.runtime.models import is_model_name, model_path, pipeline_detector
from a3d.runtime.network.cpu_support import bf16_instructions
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.structures.classes import CLASSES
from a3d.train.checkpoint import file_sha256, save_checkpoint
from a3d.train.config import apply_overrides
from a3d.train.dataset import MIN_STD, TargetStats, compute_target_stats
from a3d.train.finetune_data import (
    Recording,
    Split,
    calibration_frames,
    read_recording,
    split_recordings,
    synthetic_frames,
)
from a3d.train.loop import CHECKPOINT_NAME, TrainingInterrupted, train
from a3d.train.roidb import build_roidb

PROG = "a3d-finetune"
EXPORT_SECONDS = 90.0  # the export's fixed part: tracing, checks, int8 calibration (2 busy cores)
SCORE_AGAIN = 1.5  # the after-scoring on the held-back frames (and a busier machine), against the before's
MIN_TRAIN_SECONDS = 30.0  # less is no fine-tuning (the RoI database and the first steps alone)
CALIB_FRAMES = 16  # int8 calibration frames: half the user's (spread over the recordings), half synthetic
READ_BACK_PROBS = 0.5  # the read-back weights' class probabilities this close to the file's, at most


@dataclass(frozen=True)
class Recipe:
    """The training settings a3d-finetune uses (its --help names them); ``iterations`` is the most
    it runs, the lr steps down tenfold at 80 % of the run fitted to the budget. They are counted,
    not left to the budget alone: the 13000 a bfloat16 CPU ran in 15 minutes lost on the room and
    on other rooms. 6000 (6 to 7 minutes there; a slower machine runs what its budget holds) scored
    1.9 points more than 2000 on six rooms' held-back frames, 3.4 more where those are the room seen
    again by a robot, and lost at most 0.7 on other rooms (docs/training.md "Your own room")."""

    lr: float = 0.0001
    iterations: int = 6000
    images_per_batch: int = 2
    freeze_color: bool = True
    freeze_depth: int = 10  # the depth trunk's conv1-conv4 kept: a room's 100 frames move conv5 and the head
    dropout: float = 0.0  # the exported network's own activations trained on (module docstring, step 4)
    seed: int = 0
    min_synth_frames: int = 40  # a3d-synth frames mixed in: as many as the room's, and no fewer than this

    def synth_frames(self, asked: int | None, train_frames: int) -> int:
        """The a3d-synth frames to mix in: ``asked`` (--synth-frames), else as many as the room's
        training frames and at least ``min_synth_frames``: three views of a room beside three
        synthetic frames forgot the classes the views lack (bench.real_room: a sofa 100 -> 7.8 AP;
        with 40, kept at 100; docs/mapping.md "Real views of two rooms")."""
        return asked or max(train_frames, self.min_synth_frames)

    def overrides(self, init: Path, minutes: float, cache: Path) -> list[str]:
        precision = "bf16" if bf16_instructions() else "fp32"
        return [
            f"solver.init={init}", f"solver.lr={self.lr}", f"solver.iterations={self.iterations}",
            f"solver.lr_steps=[{round(0.8 * self.iterations)}]", f"solver.minutes={minutes}",
            f"solver.precision={precision}", "solver.frozen_norms=true", f"solver.seed={self.seed}",
            f"solver.freeze_color={13 if self.freeze_color else 0}", "data.bg_iou_low=0",
            f"solver.freeze_depth={self.freeze_depth}", f"net.dropout={self.dropout}",
            f"data.images_per_batch={self.images_per_batch}", "data.augment=false", f"data.cache_dir={cache}",
            "log.val_every=0", "log.checkpoint_every=500",
        ]  # fmt: skip


def finetune(args: argparse.Namespace, recipe: Recipe) -> Path:
    """Steps 1-6 of the module docstring for a3d-finetune's parsed flags; returns the file written."""
    start = time.monotonic()
    budget = 60.0 * args.minutes
    base_file = model_path(args.base)
    base = DetectorModel.load(base_file, args.threads)  # ModelError: one line before any work
    recordings = [read_recording(folder) for folder in args.folders]
    work = args.work or args.out.with_name(f"{args.out.stem}.finetune")
    split = split_recordings(recordings, args.holdout, work)
    mixed = recipe.synth_frames(args.synth_frames, split.train_frames)
    synth = args.synth or synthetic_frames(work, mixed, args.threads)
    _say(f"{split.train_frames} training frames of {len(recordings)} recording(s) beside {synth}, "
         f"{split.holdout_frames} held back; scoring {args.base} on them")  # fmt: skip
    scored = time.monotonic()
    before = score_on(base, split.holdout, PROG)
    present = sum(c.present for c in before.classes)
    _say(f"{args.base}'s network on the held-back frames: mAP@0.25 {100 * before.map_present(IOU):.1f} over "
         f"their {present} classes, {100 * before.map_all(IOU):.1f} over 19")  # fmt: skip
    before_pipeline = pipeline_score(args.base, split.holdout, args.threads)
    if before_pipeline is not None:
        _say(f"{args.base} as a3d-run runs it (with {before_pipeline.detector}): mAP@0.25 "
             f"{100 * before_pipeline.result.map_present(IOU):.1f} over their classes")  # fmt: skip
    export_seconds = EXPORT_SECONDS + SCORE_AGAIN * (time.monotonic() - scored)  # the "after" scores again
    _left_to_train(args.minutes, budget - (time.monotonic() - start), export_seconds)
    weights = read_back(base_file, args.threads)
    if weights.agreement.probs.max_abs > READ_BACK_PROBS:
        raise InputError(f"{base_file}: its weights read back answer unlike the file "
                         f"({weights.agreement.describe()})")  # fmt: skip
    folders = [*split.train, synth]
    init = _initial_checkpoint(weights, apply_overrides(weights.config, args.overrides), folders, work)
    train_seconds = _left_to_train(args.minutes, budget - (time.monotonic() - start), export_seconds)
    settings = [*recipe.overrides(init, train_seconds / 60, work / "cache"), *args.overrides]  # --set last
    config = apply_overrides(weights.config, settings)
    interrupted = False
    try:
        train(folders, work / "run", config, overwrite=True)
    except TrainingInterrupted as e:
        interrupted = True
        _say(f"interrupted: {e}; exporting that checkpoint")
    exported = work / "exported.onnx"
    calib = calibration_frames(split.train, synth, work, CALIB_FRAMES)
    export(argparse.Namespace(
        checkpoint=work / "run" / CHECKPOINT_NAME, output=exported, verify_frames=split.holdout, svd=None,
        int8=True, calib=calib, calib_frames=CALIB_FRAMES, opset=MIN_OPSET, score_threshold=None,
        score_calibration=split.holdout, threads=args.threads,
    ))  # fmt: skip
    card = model_card(args, base, recordings, split, synth, recipe, weights, before, interrupted)
    if before_pipeline is not None:
        card["heldout_map25_pipeline"] = {"detector": before_pipeline.detector,
                                          **_scores("before", before_pipeline.result)}  # fmt: skip
    return _write(exported, args.out, card, start, split.holdout, args.threads)


@dataclass(frozen=True)
class PipelineScore:
    """A model's pipeline with its 2D detector, scored on the held-back frames."""

    detector: str
    result: EvalResult


def pipeline_score(
    model: str | Path, folder: Path, threads: int, detector: str | None = None
) -> PipelineScore | None:
    """The pipeline a3d-run runs with ``model`` (a bundled name or a file: its network, score
    calibration and 2D detector, or ``detector`` where given, every step after the network) scored
    on ``folder``; None for a network without a 2D detector, whose pipeline is the network alone
    (score_on)."""
    pipeline = Detector.load(model, threads=threads, detector=detector)
    boxes = pipeline.config.detector
    if boxes is None:
        return None
    return PipelineScore(boxes.name, score_on(pipeline.model, folder, PROG, pipeline.config))


def _scores(when: str, result: EvalResult) -> dict:
    return {when: result.map_all(IOU), f"{when}_present": result.map_present(IOU)}


def _left_to_train(minutes: float, left: float, export_seconds: float) -> float:
    """The seconds the budget leaves to train after ``export_seconds`` for the export; InputError
    when that is less than ``MIN_TRAIN_SECONDS`` (nothing is written then)."""
    if left - export_seconds < MIN_TRAIN_SECONDS:
        raise InputError(f"--minutes {minutes:g} is too short: {max(left, 0):.0f} s are left, the export "
                         f"needs about {export_seconds:.0f} s, and less than {MIN_TRAIN_SECONDS:.0f} s would "
                         "be left to train")  # fmt: skip
    return left - export_seconds


def _initial_checkpoint(weights: ReadBack, config, folders: list[Path], work: Path) -> Path:
    """The read-back weights as an a3d-train checkpoint to fine-tune: the training frames' RoI
    database built with ``config`` (the read-back one with --set) and cached for the run, the
    heads normalised by its target statistics."""
    roidb = build_roidb(
        folders, config, work / "cache", weights.metadata.mean_sizes, progress=config.log.progress
    )
    stats = steady_stats(roidb.records, config.data.flip)
    path = work / "init.pt"
    save_checkpoint(path, {
        "iteration": 0, "config": config.to_json(), "model": normalise_heads(weights.weights, stats),
        "target_stats": stats.to_tensors(), "classes": list(CLASSES),
        "mean_sizes": torch.tensor(np.asarray(roidb.mean_sizes, np.float64)),
    })  # fmt: skip
    return path


def steady_stats(records: list, flip: bool) -> TargetStats:
    """Target statistics of all the training frames' classes together, the same for every class:
    a room holds one or two objects of a class, so a class's own statistics are degenerate (the size
    targets of a single object are all the same number: a std at its floor, normalised deltas and a
    loss hundreds of times too large)."""
    stats = compute_target_stats(records, flip)
    counts = np.bincount(np.concatenate([r.labels[: r.num_fg] for r in records]), minlength=len(stats.mean3d))
    share = (counts * (np.arange(len(counts)) > 0) / max(counts[1:].sum(), 1))[:, None]  # background: none
    for mean, std in ((stats.mean3d, stats.std3d), (stats.mean2d, stats.std2d)):
        pooled = (share * mean).sum(axis=0)
        spread = np.sqrt(np.maximum((share * (std**2 + mean**2)).sum(axis=0) - pooled**2, MIN_STD**2))
        mean[:], std[:] = pooled, spread
    return stats


def model_card(args: argparse.Namespace, base: DetectorModel, recordings: list[Recording], split: Split,
               synth: Path, recipe: Recipe, weights: ReadBack, before: EvalResult,
               interrupted: bool) -> dict:  # fmt: skip
    """``provenance["finetune"]``: what the model was fine-tuned from, on and how (the "after"
    is added from the export's score calibration)."""
    objects: Counter = Counter()
    for recording in recordings:
        objects.update(recording.objects)
    base_file = model_path(args.base)
    return {
        "base": {"model": str(args.base) if is_model_name(args.base) else str(base_file.resolve()),
                 "detector": _detector(args.base, base),
                 "sha256": file_sha256(base_file), "exported_at": base.metadata.provenance.get("exported_at"),
                 "training_data": base.metadata.provenance.get("training_data")},
        "data": {
            "recordings": [str(r.folder.resolve()) for r in recordings],
            "frames": sum(len(r.refs) for r in recordings),
            "train_frames": split.train_frames,
            "holdout_frames": split.holdout_frames,
            "holdout": f"the last {args.holdout:g} of each recording's frames",
            "objects_per_class": dict(sorted(objects.items())),
            "synthetic": str(synth.resolve()),
        },
        "recipe": {**dataclasses.asdict(recipe), "minutes": args.minutes, "pooled_layout": weights.layout,
                   "read_back_vs_file": weights.agreement.to_dict(), "interrupted": interrupted,
                   "settings": list(args.overrides)},
        "heldout_map25": {"before": before.map_all(IOU), "before_present": before.map_present(IOU)},
    }  # fmt: skip


def _detector(base_name: str, base: DetectorModel) -> str | None:
    """The 2D detector of the base's pipeline (a bundled pipeline's, or the one a base file names),
    which the fine-tuned model names in turn: running it runs the same pipeline with the new network."""
    chosen = pipeline_detector(base_name, None, base.metadata.detector)
    return None if chosen is None else str(chosen)


def _write(exported: Path, out: Path, card: dict, start: float, holdout: Path, threads: int) -> Path:
    """The exported model with the card in its provenance and the base pipeline's 2D detector
    (``card["base"]["detector"]``) in its metadata, written atomically to ``out``; where the base
    has a detector, the pipeline's "after" is scored with the exported network and that detector,
    the pipeline a3d-run runs with ``out``, so that the card holds what a3d-run gives."""
    import onnx

    model = DetectorModel.load(exported, threads=1)
    calibration = model.metadata.provenance["export"]["score_calibration"]
    scores = card["heldout_map25"]
    scores.update(after=calibration["map25"], after_present=calibration["map25_present"])
    metadata = dataclasses.replace(model.metadata, detector=card["base"]["detector"])
    compared = [("network", scores)]
    if "heldout_map25_pipeline" in card:
        after = pipeline_score(exported, holdout, threads, detector=card["base"]["detector"])
        assert after is not None  # the base's detector
        card["heldout_map25_pipeline"].update(_scores("after", after.result))
        compared.insert(0, (f"pipeline with {after.detector}", card["heldout_map25_pipeline"]))
    seconds = time.monotonic() - start
    card["seconds"] = round(seconds, 1)
    metadata = dataclasses.replace(metadata, provenance={**model.metadata.provenance, "finetune": card})
    save_model(onnx.load(str(exported)), metadata, out)
    DetectorModel.load(out, threads=1)
    for what, pair in compared:
        _say(f"held-back frames, mAP@0.25 over their classes, {what}: {100 * pair['before_present']:.1f} "
             f"before, {100 * pair['after_present']:.1f} after")  # fmt: skip
    what, pair = compared[0]
    if pair["after_present"] < pair["before_present"]:
        _say(f"warning: the fine-tuned model scores lower than {card['base']['model']} on the held-back "
             f"frames ({what}): for this room the base model stays the better choice")  # fmt: skip
    _say(f"{seconds / 60:.1f} minutes in all")
    return out


def _say(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)
