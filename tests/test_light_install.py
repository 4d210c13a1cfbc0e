"""The light edge install: without rerun (the optional ``view`` extra), a3d-run --headless and the
runtime's Python API work, and asking for a view is one clear line with exit code 2."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.samples import SAMPLE_MODEL

ROOT = Path(__file__).resolve().parents[1]

# In a fresh interpreter rerun cannot be imported (as if it were not installed); the probe runs
# a3d-run with the flags given and reports its exit code and whether anything imported rerun.
_WITHOUT_RERUN = r"""
import importlib, importlib.abc, pkgutil, sys

class NoRerun(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "rerun":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NoRerun())
import a3d.runtime
for info in pkgutil.walk_packages(a3d.runtime.__path__, "a3d.runtime."):
    if info.name != "a3d.runtime.viewer.view":  # the view itself is rerun
        importlib.import_module(info.name)
from a3d.runtime.cli.run import main
code = main(sys.argv[1:])
print("exit", code, "rerun imported:", any(m.split(".")[0] == "rerun" for m in sys.modules))
"""


def _run_without_rerun(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _WITHOUT_RERUN, *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=300, env=env)  # fmt: skip


def _one_frame(tmp_path: Path) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for path in [ROOT / "samples" / "intrinsics.json", *(ROOT / "samples").glob("synth_000000.*")]:
        shutil.copy(path, folder / path.name)
    return folder


def test_headless_run_and_api_never_import_rerun(tmp_path: Path) -> None:
    folder = _one_frame(tmp_path)
    out = tmp_path / "det.jsonl"
    model = SAMPLE_MODEL
    result = _run_without_rerun(str(folder), "--model", str(model), "--output", str(out), "--headless")
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == "exit 0 rerun imported: False"
    assert len(out.read_text().splitlines()) == 1


def test_a_view_without_rerun_is_one_line_and_exit_2(tmp_path: Path) -> None:
    folder = _one_frame(tmp_path)
    model = SAMPLE_MODEL
    save = tmp_path / "run.rrd"
    result = _run_without_rerun(str(folder), "--model", str(model), "--output", str(tmp_path / "d.jsonl"),
                                "--save", str(save))  # fmt: skip
    assert result.stdout.strip().splitlines()[-1].startswith("exit 2 ")
    assert result.stderr.strip() == (
        "a3d-run: error: rerun is not installed: the view and --save need it (pip install 'a3d[view]'); "
        "--headless alone runs without it"
    )
    assert not save.exists()


VIEW_MODES = [[], ["--serve"], ["--connect"], ["--stdout"]]


@pytest.mark.parametrize("flags", VIEW_MODES, ids=lambda flags: " ".join(flags) or "window")
def test_every_view_mode_without_rerun_names_the_extra(tmp_path: Path, flags: list[str]) -> None:
    """No display and no rerun: the line names 'a3d[view]', not --serve or a viewer that cannot start."""
    model = SAMPLE_MODEL
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = _run_without_rerun(str(_one_frame(tmp_path)), "--model", str(model), "--output",
                                str(tmp_path / "d.jsonl"), *flags, env=env)  # fmt: skip
    assert result.stdout.strip().splitlines()[-1].startswith("exit 2 ")
    assert result.stderr.strip().splitlines() == [
        "a3d-run: error: rerun is not installed: the view and --save need it (pip install 'a3d[view]'); "
        "--headless alone runs without it"
    ]
