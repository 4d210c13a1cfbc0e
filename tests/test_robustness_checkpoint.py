"""Checkpoint damage that tests/test_train_checkpoint.py does not cover.

That file covers truncated, garbage, empty and foreign files, pickles that would run code (refused,
never run) and kill -9 during a write (the previous checkpoint survives). Missing there:

- a byte flipped inside a tensor's stored data. The file stays a valid zip and a valid pickle, so
  ``torch.load`` alone would hand back a wrong weight without a word; torch.save stores a CRC-32
  for every zip record, which catches it;
- short non-zip files that torch reads as a legacy pickle: its weights-only unpickler raises
  IndexError or struct.error on some opcode sequences (random 4096-byte garbage hits this about
  1 time in 15).

load_checkpoint checks every record's CRC before torch.load and turns both into one-line
CheckpointErrors.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest
import torch

from a3d.train.checkpoint import CheckpointError, load_checkpoint, save_checkpoint


def _flipped(tmp_path: Path) -> tuple[Path, Path]:
    good, flipped = tmp_path / "checkpoint.pt", tmp_path / "flipped.pt"
    weights = torch.arange(4096, dtype=torch.float32)
    save_checkpoint(good, {"iteration": 3, "config": "{}", "model": {"fc.weight": weights}})
    data = bytearray(good.read_bytes())
    at = bytes(data).index(weights[:16].numpy().tobytes()) + 4 * 1000  # inside fc.weight[1000]
    data[at] ^= 0x40
    flipped.write_bytes(bytes(data))
    return good, flipped


def test_the_zip_records_crc_catches_a_flipped_weight_byte(tmp_path: Path) -> None:
    """What a fix can rely on: the intact file passes zipfile's CRC check, the flipped one fails it."""
    good, flipped = _flipped(tmp_path)
    with zipfile.ZipFile(good) as archive:
        assert archive.testzip() is None
    with zipfile.ZipFile(flipped) as archive:
        assert archive.testzip() is not None


def test_a_flipped_byte_in_the_weights_is_refused(tmp_path: Path) -> None:
    _, flipped = _flipped(tmp_path)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(flipped)
    assert str(info.value).startswith(f"{flipped}: ") and "corrupted" in str(info.value)


@pytest.mark.parametrize(
    "data", [b"a", b"\x80\x02a", b"\x80\x02J\x01"], ids=["append", "proto2-append", "short-int"]
)
def test_short_pickle_garbage_is_refused_with_one_line(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "garbage.pt"
    path.write_bytes(data)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)
