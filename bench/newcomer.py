"""A newcomer's first hour, replayed: the README's commands in a fresh clone, each timed.

    python bench/newcomer.py                 # the README's first block (install + samples; the suite)
    python bench/newcomer.py --whole-job     # then "The whole job" (synth, train, export, run, eval)
    python bench/newcomer.py --wheel         # the wheel as a user installs it, outside the clone
    python bench/newcomer.py --repo URL --workdir /tmp/newcomer --keep

The repository (default: the committed HEAD of this checkout) is cloned into an empty folder and
the commands are read from its README.md, not copied here: the first fenced block (the
runtime install with the samples, then ./scripts/test, which makes .venv and runs the suite)
and, with --whole-job, the fenced block under "## The whole job". Each line runs in bash in the
clone with a clean environment (no active venv); a line that sources a file (". .venv/bin/
activate") is carried into the lines after it. A block stops at its first failing command (the
next ones need its output). Prints a table of each command's exit code and wall time, written
also to WORKDIR/newcomer.md after every command, with each command's output in WORKDIR/logs/.
Exit code 0 when every command exits 0, else 1.

--wheel is the distribution as a user installs it, in the work folder beside the clone: a fresh
venv, the clone's wheel (pip wheel --no-deps, its size in MB) installed with the base
dependencies only (pip install -c constraints.txt WHEEL, no extras); then, in that install,
a3d-run without --model (the bundled default model) on a copy of samples/, a3d-run realsense
without pyrealsense2 (one line naming the extra, exit 2) and with a stub pyrealsense2 on
PYTHONPATH that serves the samples as a camera (tests/fake_realsense.py, --max-frames 3),
every console script of the wheel's entry_points.txt with --help and --version, each command
that needs an extra on a trivial argument list (one line naming the extra, exit 2), and the
README's "Python API" snippet on a sample frame. Prints a table of each command's exit code,
the one it should have, its wall time and, where a one-line error is expected, that line;
written also to WORKDIR/newcomer_wheel.md (kept), with each command's output in WORKDIR/logs/.
Exit code 0 when every row is as expected, else 1.
"""

from __future__ import annotations

import argparse
import ast
import builtins
import configparser
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```[a-z]*\n(.*?)^```", re.M | re.S)


@dataclass
class Step:
    block: str
    command: str
    code: int | None = None  # None: not run (an earlier command of its block failed)
    seconds: float = 0.0


def readme_blocks(readme: str, whole_job: bool) -> list[tuple[str, list[str]]]:
    """(name, command lines) of the README's first fenced block and, optionally, the whole job's."""
    first = FENCE.search(readme)
    if first is None:
        raise SystemExit("README.md has no fenced block")
    blocks = [("first", _lines(first.group(1)))]
    if whole_job:
        blocks.append(("whole job", _lines(block_under(readme, "The whole job"))))
    return blocks


def block_under(readme: str, heading: str, language: str = "") -> str:
    """The first fenced block (tagged ``language``, or any) of the README's section ``## heading``."""
    parts = readme.split(f"\n## {heading}\n", 1)
    fence = re.compile(rf"^```{re.escape(language) if language else '[a-z]*'}\n(.*?)^```", re.M | re.S)
    block = fence.search(parts[1].split("\n## ", 1)[0]) if len(parts) == 2 else None
    if block is None:
        kind = f"{language} " if language else ""
        raise SystemExit(f'README.md has no fenced {kind}block under "## {heading}"')
    return block.group(1)


def _lines(block: str) -> list[str]:
    return [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith("#")]


def clean_env() -> dict[str, str]:
    """The caller's environment without an active virtual environment."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    venv = os.environ.get("VIRTUAL_ENV")
    if venv:
        env["PATH"] = os.pathsep.join(
            p for p in env.get("PATH", "").split(os.pathsep) if not p.startswith(venv)
        )
    return env


def run_block(name: str, lines: list[str], clone: Path, logs: Path, steps: list[Step], report: Path) -> bool:
    carried: list[str] = []
    ok = True
    for line in lines:
        if line.startswith((". ", "source ")):
            carried.append(line)
            continue
        step = Step(name, line)
        steps.append(step)
        if not ok:
            continue
        log = logs / f"{len(steps):02d}.log"
        script = "\n".join(["set -euo pipefail", *carried, line])
        start = time.perf_counter()
        with log.open("w") as out:
            step.code = subprocess.run(["bash", "-c", script], cwd=clone, env=clean_env(), stdout=out,
                                       stderr=subprocess.STDOUT).returncode  # fmt: skip
        step.seconds = time.perf_counter() - start
        ok = step.code == 0
        report.write_text(format_table(steps))
        print(format_row(len(steps), step), flush=True)
    return ok


def eval_scores(clone: Path, since: float) -> list[str]:
    """The primary-threshold mAPs of the eval.json files a3d-eval wrote under out/ since ``since``."""
    lines = []
    for path in sorted(clone.glob("out/**/eval.json")):
        if path.stat().st_mtime >= since:
            threshold, maps = next(iter(json.loads(path.read_text())["map"].items()))
            lines.append(f"{path.relative_to(clone)}: mAP@{threshold} {100 * maps['all_classes']:.1f} "
                         f"(19 classes), {100 * maps['present_classes']:.1f} (present classes)")  # fmt: skip
    return lines


def markdown_row(cells: list[str]) -> str:
    return "| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |"


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table: the header, its rule and the rows (cells' pipes escaped)."""
    return "\n".join(markdown_row(row) for row in [header, ["---"] * len(header), *rows]) + "\n"


def _cells(number: int, step: Step) -> list[str]:
    code = "not run" if step.code is None else str(step.code)
    shown = step.command if len(step.command) <= 90 else step.command[:87] + "..."
    return [str(number), step.block, f"`{shown}`", code, f"{step.seconds:.0f}"]


def format_row(number: int, step: Step) -> str:
    return markdown_row(_cells(number, step))


def format_table(steps: list[Step]) -> str:
    rows = [_cells(i, s) for i, s in enumerate(steps, start=1)]
    return markdown_table(["#", "block", "command", "exit", "seconds"], rows)


# --wheel: the distribution as a user installs it, outside the clone.

VENV_BIN = "venv/bin/"
REPORT = "newcomer_wheel.md"
TIMEOUT_S = 1800  # one command (pip install downloads ONNX Runtime and OpenCV)
CAMERA_FRAMES = 3  # a3d-run realsense --max-frames with the stub camera

EXTRA_ARGS: dict[str, tuple[tuple[str, ...], str]] = {
    "a3d-train": (("frames", "--out", "out/run"), "train"),
    "a3d-pretrain": (("frames", "--out", "out/vgg16.pt"), "train"),
    "a3d-average": (("a.pt", "b.pt", "--out", "out/average.pt"), "train"),
    "a3d-vgg16-weights": (("vgg16.h5", "--out", "out/vgg16.pt"), "train"),
    "a3d-export": (("checkpoint.pt", "-o", "out/model.onnx"), "train"),
    "a3d-nyuv2": (("release", "out/nyuv2"), "train"),
    "a3d-finetune": (("frames", "--out", "out/model.onnx"), "train"),
}
"""The console scripts that need an extra (their NEEDS): an argument list that parses, and the extra."""

FAKE_CAMERA = '''"""A stand-in pyrealsense2 written by bench/newcomer.py --wheel: the fake SDK of the clone's
tests/fake_realsense.py serving the frame folder {frames} as a camera."""
import importlib.util
import sys
from pathlib import Path

_spec = importlib.util.spec_from_file_location("fake_realsense", {module!r})
_fake = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_fake)
sys.modules[__name__] = _fake.folder_camera(Path({frames!r}), repeat=50, period=0.2)
'''

API_PRELUDE = """# bench/newcomer.py --wheel: a sample frame as the README's snippet takes it
import json

import cv2

color = cv2.cvtColor(cv2.imread("{frame}.color.png", cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)  # uint8 RGB
depth = cv2.imread("{frame}.depth.png", cv2.IMREAD_UNCHANGED)  # uint16 millimetres
assert color.dtype == "uint8" and color.ndim == 3 and depth.dtype == "uint16", (color.dtype, depth.dtype)
with open("{intrinsics}") as _file:
    _k = json.load(_file)
fx, fy, cx, cy = _k["fx"], _k["fy"], _k["cx"], _k["cy"]

"""


@dataclass
class Check:
    """One command of --wheel, run in the work folder, and what it should do."""

    argv: list[str]
    expect: int = 0
    extra: str | None = None  # stderr should be one line naming this extra
    env: dict[str, str] = field(default_factory=dict)  # added to the clean environment (work-relative paths)
    lines: tuple[str, int | None] | None = None  # (output file, the lines it should hold; None: not written)
    stdout: str | None = None  # what stdout should start with
    code: int | None = None  # None: not run
    seconds: float = 0.0
    note: str = ""  # the first line of stderr where a one-line error is expected; or what was made
    problem: str = "not run"  # why the outcome is not as expected; "" when it is

    @property
    def command(self) -> str:
        return shlex.join([f"{name}={value}" for name, value in self.env.items()] + self.argv)


def python_api_snippet(readme: str) -> str:
    """The README's first ```python block under "## Python API"."""
    return block_under(readme, "Python API", "python")


def api_script(snippet: str, frames: str, frame: str) -> str:
    """The snippet after a prelude that reads ``frame`` of the frame folder ``frames`` into
    ``color`` (RGB uint8), ``depth`` (uint16 millimetres) and ``fx, fy, cx, cy``."""
    return API_PRELUDE.format(frame=f"{frames}/{frame}", intrinsics=f"{frames}/intrinsics.json") + snippet


def free_names(source: str) -> set[str]:
    """The names a script reads but neither binds nor imports, builtins aside."""
    tree = ast.parse(source)
    bound, read = set(dir(builtins)), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (read if isinstance(node.ctx, ast.Load) else bound).add(node.id)
        elif isinstance(node, ast.alias):
            bound.add((node.asname or node.name).split(".")[0])
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            bound.add(node.name)
    return read - bound


def console_scripts(entry_points: str) -> dict[str, str]:
    """The ``[console_scripts]`` of an entry_points.txt: command -> "module:function"."""
    parser = configparser.ConfigParser(delimiters=("=",), interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]  # names keep their case
    parser.read_string(entry_points)
    return dict(parser["console_scripts"]) if parser.has_section("console_scripts") else {}


def wheel_entry_points(wheel: Path) -> str:
    """The text of a wheel's ``*.dist-info/entry_points.txt`` ("" when it has none)."""
    with zipfile.ZipFile(wheel) as archive:
        names = [n for n in archive.namelist() if n.endswith(".dist-info/entry_points.txt")]
        return archive.read(names[0]).decode() if names else ""


def wheel_version(wheel: Path) -> str:
    """The version in a wheel's file name (``a3d-0.1.0-py3-none-any.whl``: 0.1.0)."""
    return wheel.name.split("-")[1]


def out(name: str) -> str:
    return f"out/{name}.jsonl"


def usage_plan(scripts: list[str], version: str, frames: int) -> list[Check]:
    """The expected outcomes in the base install, run from the work folder: a3d-run without --model
    on ``frames`` (the samples' copy of ``frames`` frames), on a camera without and with the stub
    SDK, asking for the view; --help and --version of every console script; each command that
    needs an extra; the README's Python API snippet (api.py)."""
    run = [VENV_BIN + "a3d-run"]
    camera = [*run, "realsense", "--headless", "--max-frames", str(CAMERA_FRAMES), "--output"]
    plan = [
        Check([*run, "frames", "--headless", "--output", out("frames")], lines=(out("frames"), frames)),
        Check([*camera, out("no_sdk")], expect=2, extra="realsense", lines=(out("no_sdk"), None)),
        Check([*camera, out("camera")], env={"PYTHONPATH": "fakecam"}, lines=(out("camera"), CAMERA_FRAMES)),
        Check([*run, "frames", "--output", out("view")], expect=2, extra="view", lines=(out("view"), None)),
        Check([*run, "--model-info", "live"]),
    ]
    for script in scripts:
        plan += [
            Check([VENV_BIN + script, "--help"], stdout="usage: "),
            Check([VENV_BIN + script, "--version"], stdout=f"a3d {version}\n"),
        ]
    for script in scripts:
        if script in EXTRA_ARGS:
            args, extra = EXTRA_ARGS[script]
            plan.append(Check([VENV_BIN + script, *args], expect=2, extra=extra))
    return [*plan, Check([VENV_BIN + "python", "api.py"])]


def verdict(check: Check, code: int, stdout: str, stderr: str, written: int | None) -> str:
    """Why a command's outcome is not the one expected ("" when it is); ``written``: the lines in
    the check's output file (None: no such file)."""
    if code != check.expect:
        last = stderr.strip().splitlines()[-1:] or [""]
        return f"exit {code}, expected {check.expect}" + (f": {last[0][:200]}" if last[0] else "")
    if check.extra is not None:
        lines = stderr.strip().splitlines()
        if len(lines) != 1 or f"a3d[{check.extra}]" not in lines[0]:
            return f"{len(lines)} lines on stderr, expected one naming a3d[{check.extra}]"
    if check.lines is not None and written != check.lines[1]:
        want = "no file" if check.lines[1] is None else f"{check.lines[1]} lines"
        return f"{check.lines[0]}: {'no file' if written is None else f'{written} lines'}, expected {want}"
    if check.stdout is not None and not stdout.startswith(check.stdout):
        return f"stdout starts {stdout[:40]!r}, expected {check.stdout!r}"
    return ""


def run_check(check: Check, work: Path, log: Path) -> None:
    """Run ``check`` in ``work`` with a clean environment; its output goes to ``log``."""
    env = clean_env() | {name: str(work / value) for name, value in check.env.items()}
    argv = [str(work / check.argv[0]) if "/" in check.argv[0] else check.argv[0], *check.argv[1:]]
    start = time.perf_counter()
    try:
        done = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
        code, stdout, stderr = done.returncode, done.stdout, done.stderr
    except subprocess.TimeoutExpired as e:
        code, stdout, stderr = 124, str(e.stdout or ""), f"timed out after {TIMEOUT_S} s"
    check.seconds = time.perf_counter() - start
    log.write_text(f"$ {check.command}\nexit {code}\n--- stdout\n{stdout}\n--- stderr\n{stderr}")
    check.code = code
    written = None
    if check.lines is not None and (work / check.lines[0]).is_file():
        written = len((work / check.lines[0]).read_text().splitlines())
        check.note = f"{written} lines written"
    if check.extra is not None:
        check.note = (stderr.strip().splitlines() or [""])[0]
    check.problem = verdict(check, code, stdout, stderr, written)


def _wheel_cells(number: int, check: Check) -> list[str]:
    code = "not run" if check.code is None else str(check.code)
    result = "no: " + check.problem if check.problem else "yes"
    return [str(number), f"`{check.command}`", code, str(check.expect), f"{check.seconds:.0f}", result,
            check.note]  # fmt: skip


def wheel_table(checks: list[Check]) -> str:
    header = ["#", "command", "exit", "expected", "seconds", "as expected", "stderr (first line) / note"]
    return markdown_table(header, [_wheel_cells(i, c) for i, c in enumerate(checks, start=1)])


def prepare_user_files(clone: Path, work: Path) -> int:
    """The samples' copy (frames/), the stub pyrealsense2 (fakecam/) and the README's Python API
    snippet after its prelude (api.py) in the work folder; the number of frames."""
    frames = work / "frames"
    shutil.copytree(clone / "samples", frames)
    (work / "out").mkdir()
    stub = work / "fakecam" / "pyrealsense2"
    stub.mkdir(parents=True)
    module = str(clone / "tests" / "fake_realsense.py")
    (stub / "__init__.py").write_text(FAKE_CAMERA.format(module=module, frames=str(frames)))
    colors = sorted(frames.glob("*.color.png"))
    snippet = python_api_snippet((clone / "README.md").read_text(encoding="utf-8"))
    (work / "api.py").write_text(api_script(snippet, "frames", colors[0].name.removesuffix(".color.png")))
    return len(colors)


def run_wheel(clone: Path, work: Path) -> list[Check]:
    """--wheel: a venv, the wheel built and installed (no extras), then the usage plan in it."""
    logs = work / "logs"
    checks: list[Check] = []

    def run(check: Check) -> bool:
        checks.append(check)
        run_check(check, work, logs / f"{len(checks):02d}.log")
        (work / REPORT).write_text(wheel_table(checks))
        print(markdown_row(_wheel_cells(len(checks), check)), flush=True)
        return not check.problem

    build = Check([VENV_BIN + "pip", "wheel", "--no-deps", "--wheel-dir", "dist", "./a3d"])
    if not (run(Check(["python3", "-m", "venv", "venv"])) and run(build)):
        return checks
    wheels = sorted((work / "dist").glob("a3d-*.whl"))
    if not wheels:
        build.problem = "no a3d-*.whl in dist/"
        return checks
    wheel = wheels[0]
    build.note = f"{wheel.name}: {wheel.stat().st_size / 1e6:.1f} MB"
    if not run(Check([VENV_BIN + "pip", "install", "-c", "a3d/constraints.txt", f"dist/{wheel.name}"])):
        return checks
    frames = prepare_user_files(clone, work)
    scripts = list(console_scripts(wheel_entry_points(wheel)))
    for check in usage_plan(scripts, wheel_version(wheel), frames):
        run(check)
    return checks


def wheel_main(clone: Path, work: Path, keep: bool) -> int:
    """Run --wheel, print its table and keep it (and the logs; all of the work folder with ``keep``
    or a failure): 0 when every row is as expected, else 1."""
    checks = run_wheel(clone, work)
    table = wheel_table(checks)
    (work / REPORT).write_text(table)
    print(table, end="")
    passed = all(not check.problem for check in checks)
    if passed and not keep:
        for path in work.iterdir():
            if path.name not in (REPORT, "logs"):
                shutil.rmtree(path) if path.is_dir() else path.unlink()
    print(f"newcomer: table in {work / REPORT}, each command's output in {work / 'logs'}")
    return 0 if passed else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--repo", default=str(ROOT), help="repository to clone (default: this checkout's HEAD)"
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--whole-job", action="store_true", help="also run the README's whole-job block")
    mode.add_argument("--wheel", action="store_true", help="install the wheel outside the clone and use it")
    parser.add_argument("--workdir", type=Path, help="empty folder to work in (default: a new temporary one)")
    parser.add_argument(
        "--keep", action="store_true", help="keep the work folder (default: deleted if all pass)"
    )
    args = parser.parse_args(argv)
    work = args.workdir or Path(tempfile.mkdtemp(prefix="a3d-newcomer-"))
    work.mkdir(parents=True, exist_ok=True)
    if any(work.iterdir()):
        parser.error(f"{work}: not empty")
    clone, logs = work / "a3d", work / "logs"
    logs.mkdir()
    subprocess.run(["git", "clone", "--quiet", args.repo, str(clone)], check=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True
    )
    print(f"newcomer: {args.repo} at {commit.stdout.strip()} cloned into {clone}", flush=True)
    if args.wheel:
        return wheel_main(clone, work, args.keep)
    steps: list[Step] = []
    report = work / "newcomer.md"
    scores = []
    for name, lines in readme_blocks((clone / "README.md").read_text(encoding="utf-8"), args.whole_job):
        started = time.time()
        run_block(name, lines, clone, logs, steps, report)
        scores += [f"{name}: {line}" for line in eval_scores(clone, started)]
    print(format_table(steps), end="")
    print("\n".join(scores))
    passed = all(s.code == 0 for s in steps)
    if passed and not args.keep:
        shutil.rmtree(work)
    else:
        print(f"newcomer: logs and table in {work}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
