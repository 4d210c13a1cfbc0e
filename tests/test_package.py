"""The distribution itself: the runtime never pulls in torch, and the wheel ships every package."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from a3d.runtime.models import MODELS

ROOT = Path(__file__).resolve().parents[1]
TOP_LEVEL = {"runtime": "a3d/runtime", "train": "a3d/train", "export": "a3d/export", "synth": "a3d/synth"}

# Runs in a fresh interpreter: any attempt to import torch (or onnx) raises, and at the end the
# module table must hold neither. Every module of a3d.runtime is imported, then each command-line
# entry point of the runtime is run with --help.
_NO_TORCH_PROBE = r"""
import importlib, importlib.abc, pkgutil, sys

class Forbid(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {"torch", "onnx", "onnxscript"}:
            raise ImportError(f"a3d.runtime imported {name}")
        return None

sys.meta_path.insert(0, Forbid())
import a3d.runtime
for info in pkgutil.walk_packages(a3d.runtime.__path__, "a3d.runtime."):
    importlib.import_module(info.name)
for cli in [m for m in sys.modules if m.startswith("a3d.runtime.cli.")]:
    main = getattr(sys.modules[cli], "main", None)
    if main is None:
        continue
    try:
        main(["--help"])
    except SystemExit as exit_:
        assert exit_.code in (0, None), (cli, exit_.code)
bad = sorted(m for m in sys.modules if m.split(".")[0] in {"torch", "onnx", "onnxscript"})
assert not bad, bad
print("runtime modules:", len([m for m in sys.modules if m.startswith("a3d.runtime")]))
"""


def test_runtime_and_its_commands_never_import_torch() -> None:
    result = subprocess.run(
        [sys.executable, "-c", _NO_TORCH_PROBE], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert result.returncode == 0, result.stderr[-3000:]
    count = int(result.stdout.strip().rsplit(" ", 1)[-1])
    assert count >= 2  # the package and at least one module were really imported


def _packages_on_disk() -> set[str]:
    found = set()
    for top, prefix in TOP_LEVEL.items():
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top)
            found.add("/".join([prefix, *rel.parts]))
    return found


@pytest.mark.slow
def test_wheel_contains_every_package(tmp_path: Path) -> None:
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(ROOT),
        ],
        check=True,
        env=env,
        timeout=600,
        capture_output=True,
    )
    (wheel,) = tmp_path.glob("a3d-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    in_wheel = {n.rsplit("/", 1)[0] for n in names if n.endswith("/__init__.py")}
    expected = _packages_on_disk()
    assert expected, "no packages found on disk"
    assert expected <= in_wheel, f"missing from the wheel: {sorted(expected - in_wheel)}"
    # Every module file of every package is shipped, not just the __init__s.
    for top, prefix in TOP_LEVEL.items():
        for module in (ROOT / top).rglob("*.py"):
            if (module.parent / "__init__.py").exists():
                arc = "/".join([prefix, *module.relative_to(ROOT / top).parts])
                assert arc in names, f"{arc} is not in the wheel"
    assert "a3d/runtime/py.typed" in names  # PEP 561: type checkers read the runtime's hints
    for name, file in MODELS.items():  # the bundled models install with the package, by short name
        assert f"a3d/runtime/models/{file}" in names, f"model {name} is not in the wheel"
