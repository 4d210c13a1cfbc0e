"""Training checkpoints: atomic writes, weights-only reads, clear refusals; the trained model.

A checkpoint is a plain ``dict`` written with ``torch.save`` and read back with
``torch.load(weights_only=True)``: only tensors, dicts, lists, tuples, strings, numbers, booleans
and None, so loading one can never run code. The training loop stores (see ``a3d.train.loop``)::

    format "a3d-checkpoint", version, iteration, config (TrainConfig JSON string),
    model (state dict), optimizer (state dict), target_stats {mean3d, std3d, mean2d, std2d},
    mean_sizes (19, 3) [l, w, h], classes (list of names)

Writes are durable atomic writes (a3d.runtime.io.atomic: a temporary file in the same folder,
fsync'ed, renamed over the old checkpoint, the folder fsync'ed), so a crash or ``kill -9`` at any
moment leaves either the previous checkpoint or the new one, never a torn file. The next save
removes temporary files that a killed writer left behind (one writer per run folder).

``load_trained`` is the one way from a checkpoint to its network, config, target statistics and
class mean sizes (validation, the torch reference detector, export, benchmarks);
``checkpoint_config`` reads the config alone (``a3d-train --resume``).
"""

from __future__ import annotations

import hashlib
import os
import pickle
import re
import struct
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from a3d.runtime.errors import ModelError
from a3d.runtime.io.atomic import atomic_write, remove_stale_temporaries
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.model import A3DNet

FORMAT = "a3d-checkpoint"
VERSION = 1
REQUIRED_KEYS = ("format", "version", "iteration", "config", "model")
_PLAIN_TYPES = (str, int, float, bool, type(None))


class CheckpointError(ModelError):
    """A file that is not a readable a3d checkpoint; the message starts with the file's path."""


def save_checkpoint(path: str | os.PathLike, payload: dict) -> None:
    """Atomically write ``payload`` (plain data and tensors only) to ``path``."""
    _check_plain(payload, "checkpoint")
    atomic_torch_save(path, {"format": FORMAT, "version": VERSION, **payload})


def atomic_torch_save(path: str | os.PathLike, obj: object) -> None:
    """torch.save to a temporary file beside ``path``, fsync'ed, then renamed over it; clears the
    temporary files of writers that were killed (one writer per run folder)."""
    remove_stale_temporaries(path)
    atomic_write(path, lambda f: torch.save(obj, f), durable=True)


def load_checkpoint(path: str | os.PathLike) -> dict:
    """Read a checkpoint weights-only onto the CPU; CheckpointError "PATH: why" if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    _check_archive(path)
    try:
        with warnings.catch_warnings():  # torch warns about foreign pickles before refusing them
            warnings.simplefilter("ignore", UserWarning)
            data = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        text = str(e)
        culprit = re.search(r"GLOBAL (\S+)", text)
        if culprit:
            raise CheckpointError(
                f"{path}: refused, not a weights-only checkpoint (loading it would import {culprit.group(1)})"
            ) from None
        detail = re.search(r"WeightsUnpickler error:\s*(.+)", text)
        reason = detail.group(1) if detail else "unpickling failed"
        raise CheckpointError(f"{path}: corrupted, truncated or not a checkpoint ({reason})") from None
    except (
        RuntimeError,
        EOFError,
        OSError,
        zipfile.BadZipFile,
        ValueError,
        KeyError,
        IndexError,
        struct.error,
    ) as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise CheckpointError(f"{path}: corrupted, truncated or not a checkpoint ({first})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an a3d checkpoint (no 'format': '{FORMAT}' entry)")
    if data.get("version") != VERSION:
        raise CheckpointError(f"{path}: a3d checkpoint version {data.get('version')!r}, expected {VERSION}")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise CheckpointError(f"{path}: a3d checkpoint without {', '.join(missing)}")
    return data


def file_sha256(path: str | os.PathLike) -> str:
    """The file's SHA-256 (hex): how provenance names a checkpoint."""
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def checkpoint_config(path: str | os.PathLike, state: dict | None = None) -> TrainConfig:
    """The training config stored in checkpoint ``path`` (read unless its ``state`` is given)."""
    state = load_checkpoint(path) if state is None else state
    return TrainConfig.from_json(state["config"], str(path))


@dataclass(frozen=True)
class Trained:
    """A trained model from its checkpoint: the network (eval mode, on the CPU), its training
    config, target statistics and class mean sizes (19, 3), and the rest of the checkpoint
    (without model and optimizer state)."""

    net: A3DNet
    config: TrainConfig
    stats: TargetStats
    mean_sizes: np.ndarray
    state: dict


def load_trained_state(path: str | os.PathLike) -> dict:
    """load_checkpoint, and the regression targets (statistics, mean sizes) the weights were trained for."""
    state = load_checkpoint(path)
    missing = [k for k in ("target_stats", "mean_sizes") if k not in state]
    if missing:
        raise CheckpointError(f"{path}: checkpoint without {', '.join(missing)} (not written by a3d-train?)")
    return state


def load_weights(net: A3DNet, weights: dict, path: str | os.PathLike) -> None:
    """``net.load_state_dict(weights)``; CheckpointError "PATH: ..." when the network configs differ."""
    try:
        net.load_state_dict(weights)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise CheckpointError(f"{path}: weights do not fit the network config ({first})") from None


def load_trained(path: str | os.PathLike, config: TrainConfig | None = None) -> Trained:
    """Read an a3d-train checkpoint; ``config`` replaces the stored one (e.g. other inference
    settings). CheckpointError "PATH: problem" if it is not usable."""
    state = load_trained_state(path)
    config = config or checkpoint_config(path, state)
    net = A3DNet(config.net)
    load_weights(net, state["model"], path)
    stats = TargetStats.from_tensors(state["target_stats"])
    rest = {k: v for k, v in state.items() if k not in ("model", "optimizer")}
    return Trained(net.eval(), config, stats, np.asarray(state["mean_sizes"], np.float64), rest)


def _check_archive(path: Path) -> None:
    """Verify every member's CRC first: a flipped byte inside a tensor would otherwise load
    silently as a wrong weight (the zip and the pickle both stay readable)."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, NotImplementedError):
        return  # not a readable zip: torch.load below names the problem
    except zlib.error as e:
        raise CheckpointError(f"{path}: corrupted checkpoint ({e})") from None
    if bad is not None:
        raise CheckpointError(f"{path}: corrupted checkpoint (member {bad} fails its CRC check)")


def _check_plain(obj, where: str) -> None:
    """Refuse anything torch.load(weights_only=True) could not read back (before writing it)."""
    if isinstance(obj, torch.Tensor) or isinstance(obj, _PLAIN_TYPES):
        return
    if isinstance(obj, dict):
        for key, value in obj.items():
            if not isinstance(key, (str, int)):
                raise TypeError(f"{where}: key {key!r} is not a str or int")
            _check_plain(value, f"{where}.{key}")
        return
    if isinstance(obj, (list, tuple)):
        for i, value in enumerate(obj):
            _check_plain(value, f"{where}[{i}]")
        return
    raise TypeError(f"{where}: {type(obj).__name__} cannot go in a weights-only checkpoint")
