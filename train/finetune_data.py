"""a3d-finetune's data: a user's recordings split into training and held-back stretches, and the
synthetic frames mixed in.

Why whole stretches: a recording's neighbouring frames are nearly the same picture, so holding
back every n-th frame would score the model on frames it has all but seen. The last share of
each recording (frames sorted by name, i.e. in time) is held back instead: the camera has moved
on to other views of the same room. The split is made of links to the user's files; the
held-back frames of all recordings go into one folder (each frame's meta.json gains its folder's
intrinsics, so recordings of several cameras can share it), the training frames into one folder
per recording, as a3d-train takes several. A frame larger than the working size a3d-run brings
every frame to (a RealSense's 1280 x 720: a3d.runtime.frontend.working_size) is written at that
size instead of linked, with its camera, its ground truth's 2D boxes and its instance map, so that
the network is fine-tuned on objects of the size in pixels it will see them at.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import sys
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import cv2

from a3d.runtime.errors import InputError
from a3d.runtime.frontend.working_size import WORKING_SIDE, working_frame
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.io.image_io import read_image_header
from a3d.runtime.network.network_input import scale_boxes
from a3d.runtime.sources.folder import (
    INTRINSICS_FILE,
    FolderSource,
    FrameRef,
    read_folder_intrinsics,
    read_frame,
    read_ground_truth,
    read_instances,
    write_frame,
)

SYNTH_SEED = (
    4242  # a3d-synth seed of the mixed-in frames: none of the bundled model's (docs/synthetic-world.md)
)


@dataclass(frozen=True)
class Recording:
    """One user folder: its frames (sorted by name) and the objects its ground truth holds per class."""

    folder: Path
    refs: list[FrameRef]
    objects: Counter


@dataclass(frozen=True)
class Split:
    """The folders a3d-finetune trains on (``train``: one per recording) and scores on (``holdout``)."""

    train: list[Path]
    holdout: Path
    train_frames: int
    holdout_frames: int


def read_recording(folder: Path) -> Recording:
    """A user's annotated frame folder; InputError naming it when it is no frame folder, has fewer
    than 2 frames, or a frame without ground truth (or with a class outside the 19)."""
    source = FolderSource(folder)  # InputError for a missing folder
    refs = source.refs
    if len(refs) < 2:
        raise InputError(f"{folder}: {len(refs)} complete frames; a3d-finetune needs 2 or more per recording")
    unlabelled = [r.name for r in refs if r.gt_path is None]
    if unlabelled:
        raise InputError(
            f"{folder}: {len(unlabelled)} of {len(refs)} frames have no ground truth (first "
            f"{unlabelled[0]}.gt.json); label the recording first (a3d-labels, docs/mapping.md)"
        )
    objects: Counter = Counter()
    for ref in refs:
        truth = read_ground_truth(ref)  # InputError for a class outside the 19
        objects.update(truth.classes)
    return Recording(folder, refs, objects)


def split_recordings(recordings: list[Recording], share: float, work: Path) -> Split:
    """The last ``share`` of each recording's frames (at least one) held back into WORK/holdout,
    the rest into WORK/train_K, as links (module docstring); WORK's earlier split is replaced."""
    for old in [work / "holdout", *work.glob("train_*")]:
        shutil.rmtree(old, ignore_errors=True)
    holdout = work / "holdout"
    holdout.mkdir(parents=True)
    train, frames = [], [0, 0]
    for k, recording in enumerate(recordings):
        held = max(1, math.ceil(share * len(recording.refs)))
        folder = work / f"train_{k}"
        folder.mkdir()
        intrinsics = recording.folder / INTRINSICS_FILE
        if intrinsics.is_file():
            os.symlink(intrinsics.resolve(), folder / INTRINSICS_FILE)
        for ref in recording.refs[: len(recording.refs) - held]:
            _link(ref, folder, ref.name)
        for ref in recording.refs[len(recording.refs) - held :]:
            _link(ref, holdout, f"r{k}_{ref.name}", intrinsics if intrinsics.is_file() else None)
        train.append(folder)
        frames[0] += len(recording.refs) - held
        frames[1] += held
    return Split(train, holdout, *frames)


def calibration_frames(train: list[Path], synth: Path, work: Path, count: int) -> Path:
    """WORK/calib: ``count`` frames for the int8 calibration, half spread evenly over the training
    frames of the recordings, half over the synthetic ones. The first frames of one recording are
    a few seconds of one view, and ranges fitted to them alone clip what other rooms and views
    need (docs/training.md "Your own room")."""
    calib = work / "calib"
    shutil.rmtree(calib, ignore_errors=True)
    calib.mkdir(parents=True)
    own = [(folder, ref) for folder in train for ref in FolderSource(folder).refs]
    mixed = [(synth, ref) for ref in FolderSource(synth).refs]
    for k, (pool, take) in enumerate(((own, count - count // 2), (mixed, count // 2))):
        for i in range(min(take, len(pool))):
            folder, ref = pool[i * len(pool) // take]
            intrinsics = folder / INTRINSICS_FILE
            _link(ref, calib, f"c{k}_{i:03d}", intrinsics if intrinsics.is_file() else None)
    return calib


def _link(ref: FrameRef, folder: Path, name: str, intrinsics: Path | None = None) -> None:
    """Link a frame's files into ``folder`` as frame ``name``; with ``intrinsics`` its meta.json is
    written instead, with the folder's intrinsics in it. A frame larger than the working size is
    written at it instead (module docstring)."""
    if max(read_image_header(ref.color_path).size) > WORKING_SIDE:
        _write_working_size(ref, folder, name)
        return
    for path in (ref.color_path, ref.depth_path, ref.gt_path, ref.instances_path, ref.proposals_path):
        if path is not None:
            os.symlink(path.resolve(), folder / (name + path.name[len(ref.name) :]))
    if ref.meta_path is None:
        return
    target = folder / f"{name}.meta.json"
    if intrinsics is None:
        os.symlink(ref.meta_path.resolve(), target)
        return
    meta = json.loads(ref.meta_path.read_text(encoding="utf-8"))
    meta.setdefault("intrinsics", json.loads(intrinsics.read_text(encoding="utf-8")))
    atomic_write_bytes(target, json.dumps(meta).encode("utf-8"))


def synthetic_frames(work: Path, frames: int, workers: int = 2) -> Path:
    """``frames`` a3d-synth frames of the world the bundled model trained on (``--world real``,
    seed ``SYNTH_SEED``) in WORK/synth/train, made once and kept for later runs."""
    from a3d.synth.cli import main as synth_main

    out = work / "synth"
    done = out / "train"
    if done.is_dir() and len(FolderSource(done).refs) == frames:
        return done
    shutil.rmtree(out, ignore_errors=True)
    argv = [
        str(out),
        "--frames",
        str(frames),
        "--seed",
        str(SYNTH_SEED),
        "--world",
        "real",
        "--split",
        "test=0",
    ]
    with contextlib.redirect_stdout(sys.stderr):  # its statistics are a side note here
        if synth_main([*argv, "--workers", str(workers)]) != 0:
            raise InputError(f"{out}: a3d-synth could not make the synthetic frames")
    return done


def _write_working_size(ref: FrameRef, folder: Path, name: str) -> None:
    """Frame ``ref`` written into ``folder`` as ``name`` at the working size: colour, depth and
    camera as a3d-run brings it there, its ground truth's 2D boxes and its instance map with them."""
    frame = read_frame(ref, read_folder_intrinsics(ref.color_path.parent))
    working = working_frame(frame, WORKING_SIDE)
    small = working.frame
    truth = read_ground_truth(ref)
    if truth is not None:
        truth = replace(
            truth,
            boxes2d_visible=scale_boxes(truth.boxes2d_visible, working.sx, working.sy),
            boxes2d_amodal=scale_boxes(truth.boxes2d_amodal, working.sx, working.sy),
        )
    instances = read_instances(ref)
    if instances is not None:
        instances = cv2.resize(instances, small.image_size[::-1], interpolation=cv2.INTER_NEAREST)
    write_frame(
        folder, name, small.color, small.depth, R_tilt=small.R_tilt, intrinsics_override=small.intrinsics,
        gt=truth, instances=instances, pose=small.pose,
    )  # fmt: skip
