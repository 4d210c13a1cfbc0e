"""bench/newcomer.py reads the README's commands as a newcomer would type them."""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from a3d.runtime import extras

ROOT = Path(__file__).resolve().parents[1]


def _newcomer():
    spec = importlib.util.spec_from_file_location("newcomer", ROOT / "bench" / "newcomer.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_the_readme_blocks_it_runs() -> None:
    blocks = dict(_newcomer().readme_blocks((ROOT / "README.md").read_text(encoding="utf-8"), whole_job=True))
    first, job = blocks["first"], blocks["whole job"]
    assert len(first) == 2 and first[1] == "./scripts/test"
    assert "-c constraints.txt" in first[0] and "a3d-run samples/" in first[0] and "a3d-eval" in first[0]
    assert job[0] == ". .venv/bin/activate"  # a fresh clone's shell has no venv active
    assert [line.split()[0] for line in job[1:]] == [
        "a3d-synth",
        "a3d-train",
        "a3d-export",
        "a3d-run",
        "a3d-eval",
    ]
    assert "--config cpu-tiny" in job[2]


def test_a_failing_command_stops_its_block(tmp_path: Path) -> None:
    newcomer = _newcomer()
    steps: list = []
    report = tmp_path / "table.md"
    lines = ["export A=1", 'test "$A" = 1 && false', "echo never"]
    assert not newcomer.run_block("b", lines, tmp_path, tmp_path, steps, report)
    assert [s.code for s in steps] == [0, 1, None]
    assert report.read_text().splitlines()[-1] == '| 2 | b | `test "$A" = 1 && false` | 1 | 0 |'


# --wheel: the pure pieces (the install itself runs only in the bench).

SNIPPET_INPUTS = {"color", "depth", "fx", "fy", "cx", "cy"}


def _scripts() -> dict[str, str]:
    """The installed a3d's console scripts (pyproject.toml's [project.scripts])."""
    points = importlib.metadata.distribution("a3d").entry_points
    return {point.name: point.value for point in points if point.group == "console_scripts"}


def test_the_python_api_snippet_gets_every_name_it_reads_from_the_prelude() -> None:
    newcomer = _newcomer()
    snippet = newcomer.python_api_snippet((ROOT / "README.md").read_text(encoding="utf-8"))
    assert "Detector.load(" in snippet and ".detect(color, depth, (fx, fy, cx, cy))" in snippet
    assert newcomer.free_names(snippet) == SNIPPET_INPUTS  # what the prelude must provide
    script = newcomer.api_script(snippet, "frames", "synth_000000")
    compile(script, "api.py", "exec")
    assert newcomer.free_names(script) == set()
    assert newcomer.free_names("import numpy as np\ndef f(a):\n    return np.add(a, b)\n") == {"b"}


def test_the_prelude_reads_a_sample_frame_as_the_snippet_expects(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    names: dict = {}
    exec(_newcomer().api_script("", "samples", "synth_000000"), names)
    bgr = cv2.imread("samples/synth_000000.color.png", cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(names["color"], bgr[..., ::-1])  # RGB
    assert names["depth"].dtype == np.uint16 and names["depth"].shape == bgr.shape[:2]
    assert 500 < names["depth"][names["depth"] > 0].mean() < 10000  # millimetres
    k = json.loads((ROOT / "samples" / "intrinsics.json").read_text())
    assert (names["fx"], names["fy"], names["cx"], names["cy"]) == (k["fx"], k["fy"], k["cx"], k["cy"])


def test_a_section_without_the_block_is_one_line() -> None:
    newcomer = _newcomer()
    readme = "# a\n## Python API\ntext\n## Next\n```python\nx = 1\n```\n"
    with pytest.raises(SystemExit, match='no fenced python block under "## Python API"'):
        newcomer.python_api_snippet(readme)  # the next section's block is not the API's
    assert newcomer.block_under(readme, "Next", "python") == "x = 1\n"


def test_console_scripts_are_read_from_the_wheel(tmp_path: Path) -> None:
    newcomer = _newcomer()
    scripts = _scripts()
    wheel = tmp_path / "a3d-0.1.0-py3-none-any.whl"
    text = "[console_scripts]\n" + "".join(f"{name} = {target}\n" for name, target in scripts.items())
    with zipfile.ZipFile(wheel, "w") as archive:
        archive.writestr("a3d/__init__.py", "")
        archive.writestr("a3d-0.1.0.dist-info/entry_points.txt", text + "\n[other]\nx = y:z\n")
    assert newcomer.console_scripts(newcomer.wheel_entry_points(wheel)) == scripts
    assert newcomer.wheel_version(wheel) == "0.1.0"
    bare = tmp_path / "b-2.0-py3-none-any.whl"
    with zipfile.ZipFile(bare, "w") as archive:
        archive.writestr("b/__init__.py", "")
    assert newcomer.console_scripts(newcomer.wheel_entry_points(bare)) == {}


def test_the_extra_table_is_each_commands_needs_and_its_arguments_reach_the_check(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    newcomer = _newcomer()
    needs = {}
    for script, target in _scripts().items():
        module = importlib.import_module(target.split(":")[0])
        if getattr(module, "NEEDS", None) is not None:
            needs[script] = (module, module.NEEDS.extra)
    table = {script: extra for script, (_, extra) in newcomer.EXTRA_ARGS.items()}
    assert {script: extra for script, (_, extra) in needs.items()} == table
    monkeypatch.setattr(extras, "installed", lambda module: False)  # as in the base install
    for script, (args, extra) in newcomer.EXTRA_ARGS.items():
        assert needs[script][0].main(list(args)) == 2, script
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"{script}: needs the '{extra}' extra: "), err


def test_the_usage_plan() -> None:
    newcomer = _newcomer()
    scripts = list(_scripts())
    plan = newcomer.usage_plan(scripts, "0.1.0", frames=6)
    assert all("--model" not in check.argv for check in plan)  # the bundled default model
    assert plan[0].argv[1:3] == ["frames", "--headless"] and plan[0].lines == ("out/frames.jsonl", 6)
    for script in scripts:
        flags = {c.argv[1]: c for c in plan if c.argv[0] == f"venv/bin/{script}" and len(c.argv) == 2}
        assert flags["--help"].expect == 0 and flags["--version"].stdout == "a3d 0.1.0\n", script
    failing = {(c.argv[0].removeprefix("venv/bin/"), c.extra) for c in plan if c.expect != 0}
    assert all(c.extra for c in plan if c.expect != 0)  # every expected failure is one line naming an extra
    assert failing == {(s, e) for s, (_, e) in newcomer.EXTRA_ARGS.items()} | {
        ("a3d-run", "realsense"),
        ("a3d-run", "view"),
    }
    (camera,) = [c for c in plan if c.env]
    assert camera.env == {"PYTHONPATH": "fakecam"} and camera.argv[1] == "realsense" and camera.expect == 0
    assert camera.command.startswith("PYTHONPATH=fakecam venv/bin/a3d-run realsense --headless --max-frames")
    assert plan[-1].argv == ["venv/bin/python", "api.py"]


@pytest.mark.parametrize(
    ("check", "code", "stdout", "stderr", "written", "problem"),
    [
        ({"lines": ("o.jsonl", 6)}, 0, "", "", 6, ""),
        ({"lines": ("o.jsonl", 6)}, 0, "", "", 5, "o.jsonl: 5 lines, expected 6 lines"),
        ({"lines": ("o.jsonl", 6)}, 0, "", "", None, "o.jsonl: no file, expected 6 lines"),
        ({}, 1, "", "warming up\nboom\n", None, "exit 1, expected 0: boom"),
        ({"expect": 2, "extra": "train"}, 2, "", "x: needs the 'train' extra: pip install 'a3d[train]'", None,
         ""),
        ({"expect": 2, "extra": "train"}, 2, "", "Traceback\nImportError: torch\n", None,
         "2 lines on stderr, expected one naming a3d[train]"),
        ({"expect": 2, "extra": "view"}, 2, "", "x: error: no such folder\n", None,
         "1 lines on stderr, expected one naming a3d[view]"),
        ({"expect": 2, "extra": "view", "lines": ("v.jsonl", None)}, 2, "", "pip install 'a3d[view]'", 0,
         "v.jsonl: 0 lines, expected no file"),
        ({"stdout": "a3d 0.1.0\n"}, 0, "a3d unknown\n", "", None,
         "stdout starts 'a3d unknown\\n', expected 'a3d 0.1.0\\n'"),
    ],
)  # fmt: skip
def test_the_verdict_on_an_outcome(
    check: dict, code: int, stdout: str, stderr: str, written: int | None, problem: str
) -> None:
    newcomer = _newcomer()
    assert newcomer.verdict(newcomer.Check(["cmd"], **check), code, stdout, stderr, written) == problem


def test_the_wheel_table() -> None:
    newcomer = _newcomer()
    done = newcomer.Check(["venv/bin/a3d-x", "a|b"], expect=2, extra="train", code=2, seconds=1.4, problem="",
                          note="a3d-x: needs the 'train' extra")  # fmt: skip
    lines = newcomer.wheel_table([done, newcomer.Check(["venv/bin/python", "api.py"])]).splitlines()
    assert lines[0].startswith("| # | command | exit | expected | seconds | as expected |")
    assert lines[2] == "| 1 | `venv/bin/a3d-x 'a\\|b'` | 2 | 2 | 1 | yes | a3d-x: needs the 'train' extra |"
    assert lines[3] == "| 2 | `venv/bin/python api.py` | not run | 0 | 0 | no: not run |  |"


def test_the_user_files_and_the_stub_camera(tmp_path: Path) -> None:
    newcomer = _newcomer()
    assert newcomer.prepare_user_files(ROOT, tmp_path) == 6
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == sorted(
        p.name for p in (ROOT / "samples").iterdir()
    )
    compile((tmp_path / "api.py").read_text(), "api.py", "exec")
    probe = (
        "import pyrealsense2 as rs\n"
        "start = rs.pipeline()\n"
        "profile = start.start(rs.config())\n"
        "k = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()\n"
        "ok, frames = start.try_wait_for_frames(1000)\n"
        "print(ok, frames.get_color_frame().get_data().shape, k.width, k.height, round(k.fx, 3))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "fakecam")}
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=99
    )
    assert result.returncode == 0, result.stderr[-2000:]
    fx = json.loads((ROOT / "samples" / "intrinsics.json").read_text())["fx"]
    assert result.stdout.split() == ["True", "(427,", "561,", "3)", "561", "427", str(round(fx, 3))]
