"""Every command in the base install (numpy, onnxruntime, OpenCV, tqdm): --help and --version work
without the command's extra, and running a command whose extra is missing is one line naming it
(``a3d-train: needs the 'train' extra: pip install 'a3d[train]' (torch is missing)``), exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from a3d.runtime.cli.common import command
from a3d.runtime.extras import EXTRAS, MissingExtra, Needs, installed

OPTIONAL = sorted({module for modules in EXTRAS.values() for module in modules})
# What each command needs, and arguments that would start its work.
NEEDING = {
    "a3d-train": ("torch", ["data", "--out", "run"]),
    "a3d-pretrain": ("torch", ["data", "--out", "w.pt"]),
    "a3d-average": ("torch", ["a.pt", "b.pt", "--out", "soup.pt"]),
    "a3d-export": ("torch", ["run/checkpoint.pt", "-o", "model.onnx"]),
    "a3d-nyuv2": ("scipy", ["release", "out"]),
    "a3d-vgg16-weights": ("torch", ["vgg16.h5", "--out", "vgg16.pt"]),
}

# A fresh interpreter in which no optional module can be imported (as in the base install) runs
# each console script's entry point with the arguments given; it reports the exit code and the
# stderr lines of each call as JSON.
_BASE_INSTALL = r"""
import contextlib, importlib.abc, io, json, sys
from importlib.metadata import entry_points

class Missing(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

BLOCKED = set(json.loads(sys.argv[1]))
sys.meta_path.insert(0, Missing())
calls = json.loads(sys.argv[2])
scripts = {ep.name: ep for ep in entry_points(group="console_scripts") if ep.name.startswith("a3d-")}
report = []
for name, args in calls:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = scripts[name].load()(args)
        except SystemExit as done:
            code = done.code
    report.append([name, args, code, err.getvalue().splitlines()])
print(json.dumps(report))
"""


Call = tuple[str, list[str]]  # a console script and its arguments


def _in_base_install(calls: list[Call], cwd: Path) -> list[tuple[str, list[str], int, list[str]]]:
    result = subprocess.run(
        [sys.executable, "-c", _BASE_INSTALL, json.dumps(OPTIONAL), json.dumps(calls)],
        capture_output=True, text=True, cwd=cwd, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    return [tuple(row) for row in json.loads(result.stdout)]


def test_help_version_and_missing_extras_in_the_base_install(tmp_path: Path) -> None:
    names = sorted(ep.name for ep in entry_points(group="console_scripts") if ep.name.startswith("a3d-"))
    calls = [(name, [flag]) for name in names for flag in ("--help", "--version")]
    calls += [(name, args) for name, (_, args) in NEEDING.items()]
    report = _in_base_install(calls, cwd=tmp_path)  # the relative paths of NEEDING are never made
    for name, args, code, err in report[: 2 * len(names)]:
        assert (code, err) == (0, []), f"{name} {args[0]} without the extras: exit {code}, {err}"
    for name, _, code, err in report[2 * len(names) :]:
        module = NEEDING[name][0]
        assert code == 2, f"{name}: exit {code}: {err}"
        assert err == [f"{name}: needs the 'train' extra: pip install 'a3d[train]' ({module} is missing)"]


def test_needs_names_the_first_missing_module() -> None:
    present = Needs("train", ("numpy",))
    present.check()  # numpy is always there
    expected = r"^needs the 'view' extra: pip install 'a3d\[view\]' \(no_such_module_a3d is missing\)$"
    with pytest.raises(MissingExtra, match=expected):
        Needs("view", ("numpy", "no_such_module_a3d")).check()
    assert installed("numpy") and not installed("no_such_module_a3d")


def test_a_lazy_import_of_an_extra_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """A module of an extra that a command imports late (after its checks) still ends in one line."""

    @command("a3d-x")
    def main(argv: list[str] | None = None) -> int:
        raise ModuleNotFoundError("No module named 'matplotlib'", name="matplotlib")

    assert main([]) == 2
    assert capsys.readouterr().err.strip() == (
        "a3d-x: needs the 'train' extra: pip install 'a3d[train]' (matplotlib is missing)"
    )

    @command("a3d-y")
    def broken(argv: list[str] | None = None) -> int:
        raise ModuleNotFoundError("No module named 'a3d.nothing'", name="a3d.nothing")

    with pytest.raises(ModuleNotFoundError):  # a module of no extra: a broken install, traceback kept
        broken([])


def test_ray_without_ray_is_one_line(tmp_path: Path) -> None:
    """a3d-run --ray says which extra it needs before looking at anything else (the folder is not there)."""
    [(_, _, code, err)] = _in_base_install([("a3d-run", ["frames", "--ray", "--headless"])], cwd=tmp_path)
    assert (code, err) == (2, ["a3d-run: needs the 'ray' extra: pip install 'a3d[ray]' (ray is missing)"])
