"""a3d-run killed mid-folder (Ctrl-C, kill -9), then ``--resume``: the same file as one clean run.

The command runs as a subprocess on a real exported model (tests/conftest.py) over a folder of
FRAMES frames (three scenes, hard-linked under new names: ~0.1 s a frame), and is killed as soon
as its output has a complete line, so well before the end. After kill -9 every line of the file
must parse (a crash never leaves a partial line); after either kill ``--resume`` must finish the
folder without redoing a written frame, and the file must equal the clean run's, timing aside.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from a3d.runtime.io.detections_io import parse_line
from tests.helpers.runtime_frames import write_scene_folder

FRAMES = 24

pytestmark = pytest.mark.slow  # kills a3d-run processes and resumes them


def _command(folder: Path, model: Path, output: Path, *extra: str) -> list[str]:
    return [
        *(sys.executable, "-m", "a3d.runtime.cli.run", str(folder), "--model", str(model)),
        *("--output", str(output), "--headless", "--threads", "1", *extra),
    ]


def _lines(path: Path) -> list[dict]:
    """The file's lines parsed, timing left out (the only field that differs between runs)."""
    return [
        {k: v for k, v in json.loads(line).items() if k != "timing"} for line in path.read_text().splitlines()
    ]


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = write_scene_folder(tmp_path_factory.mktemp("kill") / "frames", ["s0", "s1", "s2"])
    for k in range(FRAMES):
        for suffix in ("color.png", "depth.png", "meta.json"):
            os.link(folder / f"s{k % 3}.{suffix}", folder / f"f{k:03d}.{suffix}")
    for path in folder.glob("s?.*"):
        path.unlink()
    return folder


@pytest.fixture(scope="module")
def clean(folder: Path, tiny_model: Path, tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    output = tmp_path_factory.mktemp("clean") / "clean.jsonl"
    subprocess.run(_command(folder, tiny_model, output), check=True, capture_output=True, timeout=300)
    lines = _lines(output)
    assert [line["frame"] for line in lines] == [f"f{k:03d}" for k in range(FRAMES)]
    return lines


def _kill_after_first_line(
    command: list[str], output: Path, sig: signal.Signals
) -> subprocess.CompletedProcess:
    # A shell starts background jobs with SIGINT ignored, and an ignored signal stays ignored
    # across exec (Python then installs no KeyboardInterrupt handler): give a3d-run the default
    # disposition, as from a terminal, whatever started this test run.
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while not (output.exists() and b"\n" in output.read_bytes()):
        assert process.poll() is None and time.monotonic() < deadline, "a3d-run ended before writing a line"
        time.sleep(0.01)
    process.send_signal(sig)
    stdout, stderr = process.communicate(timeout=60)
    return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)


@pytest.mark.parametrize(
    ("sig", "status", "extra"),
    [(signal.SIGINT, 130, ("--overlap", "on")), (signal.SIGKILL, -signal.SIGKILL, ())],
    ids=["sigint-overlap", "kill-9"],
)
def test_killed_run_resumes_to_the_clean_output(
    sig: signal.Signals,
    status: int,
    extra: tuple[str, ...],
    folder: Path,
    tiny_model: Path,
    clean: list[dict],
    tmp_path: Path,
) -> None:
    output = tmp_path / "detections.jsonl"
    killed = _kill_after_first_line(_command(folder, tiny_model, output, *extra), output, sig)

    assert killed.returncode == status, killed.stderr
    assert "Traceback" not in killed.stderr
    if sig == signal.SIGINT:
        assert "interrupted after" in killed.stderr and "--resume continues" in killed.stderr
    data = output.read_bytes()
    assert data.endswith(b"\n"), "a partial line was left behind"
    written = data.decode().splitlines()
    for number, line in enumerate(written, start=1):
        parse_line(line, f"{output}:{number}")  # raises InputError on a damaged line
    assert 1 <= len(written) < FRAMES, "killed too late to test anything"

    resumed = subprocess.run(_command(folder, tiny_model, output, "--resume"), capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{FRAMES - len(written)} frames written" in resumed.stderr
    assert f"{len(written)} already there" in resumed.stderr
    assert output.read_text().splitlines()[: len(written)] == written  # kept byte for byte
    assert _lines(output) == clean
