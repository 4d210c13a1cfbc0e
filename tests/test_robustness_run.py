"""a3d-run (a subprocess, a real exported model) over a folder that mixes good frames with every
kind of bad input of docs/formats.md "Frame format".

Each bad frame must be named on exactly one stderr line with its problem, the good frames must
come out exactly as a run over the good frames alone does (timing aside), the exit status is 1
and nothing crashes. Documented non-failures are checked too: a frame whose depth is all zero is
processed (no detections, one warning line), and a file that belongs to no frame (notes.txt)
is no problem at all.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime.sources.folder import write_frame
from a3d.runtime.structures.geometry import rtilt_from_pitch_roll
from tests.helpers.runtime_frames import H, K, W, scene

GOOD = ("good_1", "good_2", "good_3")  # good_2 without R_tilt: gravity from its depth (a fallback here)
R_TILT = rtilt_from_pitch_roll(np.radians(-9.0), np.radians(1.0))


def run_cli(folder: Path, model: Path, output: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "a3d.runtime.cli.run", str(folder), "--model", str(model)]
    command += ["--output", str(output), "--headless", "--threads", "1"]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def without_timing(path: Path) -> dict[str, dict]:
    """The output's lines by frame, each parsed, without its timing (the only field that varies)."""
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    return {line.pop("frame"): {k: v for k, v in line.items() if k != "timing"} for line in lines}


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _frame(folder: Path, name: str, **options) -> None:
    """A frame that is good until the caller breaks one of its files (per-frame intrinsics)."""
    color, depth = scene(11)
    write_frame(folder, name, color, depth, intrinsics_override=K, **options)


def _truncated_png(folder: Path) -> None:
    _frame(folder, "truncated")
    path = folder / "truncated.color.png"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _zero_bytes(folder: Path) -> None:
    _frame(folder, "zero_bytes")
    (folder / "zero_bytes.depth.png").write_bytes(b"")


def _other_size(folder: Path) -> None:
    _frame(folder, "other_size")
    cv2.imwrite(str(folder / "other_size.depth.png"), np.full((H - 8, W), 2000, np.uint16))


def _greyscale(folder: Path) -> None:
    _frame(folder, "greyscale")
    cv2.imwrite(str(folder / "greyscale.color.png"), scene(11)[0][..., 1])


def _depth_8bit(folder: Path) -> None:
    _frame(folder, "depth_8bit")
    cv2.imwrite(str(folder / "depth_8bit.depth.png"), (scene(11)[1] * 50).astype(np.uint8))


def _millimetres(folder: Path) -> None:
    color, depth = scene(11)
    write_frame(folder, "millimetres", color, depth * 1000, intrinsics_override=K, depth_format="npy")


def _nan_depth(folder: Path) -> None:
    _frame(folder, "nan_depth", depth_format="npy")
    depth = np.load(folder / "nan_depth.depth.npy")
    depth[5, 7] = np.nan
    np.save(folder / "nan_depth.depth.npy", depth)


def _no_intrinsics(folder: Path) -> None:
    color, depth = scene(11)
    write_frame(folder, "no_intrinsics", color, depth, R_tilt=R_TILT)  # meta.json without intrinsics


def _not_a_rotation(folder: Path) -> None:
    _frame(folder, "not_rotation")
    meta = {"intrinsics": K.to_dict(), "R_tilt": (2.0 * R_TILT).tolist()}
    (folder / "not_rotation.meta.json").write_text(json.dumps(meta))


def _huge(folder: Path) -> None:
    """A 57-byte PNG whose header claims 100000 x 100000 pixels (30 GB decoded)."""
    _frame(folder, "huge")
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 2, 0, 0, 0)
    signature = b"\x89PNG\r\n\x1a\n"
    (folder / "huge.color.png").write_bytes(signature + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IEND", b""))


def _bmp(folder: Path) -> None:
    _frame(folder, "bitmap")
    (folder / "bitmap.color.png").unlink()
    cv2.imwrite(str(folder / "bitmap.color.bmp"), scene(11)[0])


def _gif_as_png(folder: Path) -> None:
    _frame(folder, "gif")
    (folder / "gif.color.png").write_bytes(b"GIF89a" + bytes(64))


# bad frame -> (how to write it, the file its line must name, what its line must say)
BAD: dict[str, tuple[Callable[[Path], None], str, str]] = {
    "truncated": (_truncated_png, "truncated.color.png", "PNG is truncated"),
    "zero_bytes": (_zero_bytes, "zero_bytes.depth.png", "file is empty (0 bytes)"),
    "other_size": (_other_size, "other_size.depth.png", f"depth is {H - 8}x{W} but colour is {H}x{W}"),
    "greyscale": (_greyscale, "greyscale.color.png", "colour image is greyscale"),
    "depth_8bit": (_depth_8bit, "depth_8bit.depth.png", "depth PNG is 8-bit; expected 16-bit millimetres"),
    "millimetres": (_millimetres, "millimetres.depth.npy", "depth values look like millimetres"),
    "nan_depth": (_nan_depth, "nan_depth.depth.npy", "depth has 1 NaN/inf values"),
    "no_intrinsics": (
        _no_intrinsics,
        "intrinsics.json",
        "missing, and no_intrinsics.meta.json has no intrinsics",
    ),
    "not_rotation": (_not_a_rotation, "not_rotation.meta.json", "R_tilt: not a proper rotation"),
    "huge": (_huge, "huge.color.png", "image is 100000x100000, above the limit"),
    "bitmap": (_bmp, "bitmap.color.bmp", "unsupported color file type .bmp"),
    "gif": (_gif_as_png, "gif.color.png", "not a PNG or JPEG file"),
}


@pytest.mark.slow  # the exported tiny model (conftest) and a3d-run processes
def test_bad_frames_are_reported_once_and_the_good_ones_match_a_clean_run(
    tmp_path: Path, tiny_model: Path
) -> None:
    folder = tmp_path / "frames"  # no intrinsics.json: every good frame carries its own
    folder.mkdir()
    for i, name in enumerate(GOOD):
        color, depth = scene(i)
        write_frame(
            folder, name, color, depth, R_tilt=None if name == "good_2" else R_TILT, intrinsics_override=K
        )
    clean = run_cli(folder, tiny_model, tmp_path / "clean.jsonl")
    assert clean.returncode == 0, clean.stderr

    for write, _, _ in BAD.values():
        write(folder)
    color, depth = scene(12)
    write_frame(folder, "zero_depth", color, np.zeros_like(depth), R_tilt=R_TILT, intrinsics_override=K)
    (folder / "notes.txt").write_text("not a frame, not a problem")
    mixed = run_cli(folder, tiny_model, tmp_path / "mixed.jsonl")

    assert mixed.returncode == 1
    assert "Traceback" not in mixed.stderr and not mixed.stdout
    err = mixed.stderr.splitlines()
    summary = f"a3d-run: {len(GOOD) + 1} frames written to {tmp_path / 'mixed.jsonl'}, {len(BAD)} failed"
    assert err[-1] == summary
    warnings = [line for line in err if line.startswith("a3d-run: warning: ")]
    too_few = "too few surface normals"  # the small test scene has too few for gravity: a fallback, said
    assert warnings == [
        f"a3d-run: warning: {folder / 'good_2.color.png'}: gravity fallback: camera axes "
        f"(raw depth: {too_few}; filled depth: {too_few})",
        f"a3d-run: warning: {folder / 'zero_depth.depth.png'}: depth has no valid pixels (all zero)",
    ]
    reports = ("a3d-run: summary: ", "a3d-run: progress: ")  # the end-of-run summary, non-TTY progress
    problems = [line for line in err[:-1] if line not in warnings and not line.startswith(reports)]
    assert len(problems) == len(BAD), "\n".join(problems)
    for name, (_, file, says) in BAD.items():
        named = [line for line in problems if f"{folder / file}:" in line and name in line]
        assert len(named) == 1, (name, problems)
        assert named[0].startswith(f"a3d-run: {folder / file}: ") and says in named[0], named[0]

    got, want = without_timing(tmp_path / "mixed.jsonl"), without_timing(tmp_path / "clean.jsonl")
    assert list(got) == sorted([*GOOD, "zero_depth"])
    zero = got.pop("zero_depth")
    assert zero["detections"] == [] and zero["R_tilt"] == R_TILT.tolist()
    assert got == want  # the good frames, bit for bit
    assert all(len(line["detections"]) > 0 for line in want.values())
