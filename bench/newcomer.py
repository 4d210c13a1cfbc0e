"""A newcomer's first hour, replayed: the README's commands in a fresh clone, each timed.

    python bench/newcomer.py                 # the README's first block (install + samples; the suite)
    python bench/newcomer.py --whole-job     # then "The whole job" (synth, train, export, run, eval)
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
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
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
        section = readme.split("\n## The whole job", 1)
        block = FENCE.search(section[1]) if len(section) == 2 else None
        if block is None:
            raise SystemExit('README.md has no fenced block under "## The whole job"')
        blocks.append(("whole job", _lines(block.group(1))))
    return blocks


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


def format_row(number: int, step: Step) -> str:
    code = "not run" if step.code is None else str(step.code)
    shown = step.command if len(step.command) <= 90 else step.command[:87] + "..."
    return f"| {number} | {step.block} | `{shown}` | {code} | {step.seconds:.0f} |"


def format_table(steps: list[Step]) -> str:
    rows = [format_row(i, s) for i, s in enumerate(steps, start=1)]
    return (
        "\n".join(["| # | block | command | exit | seconds |", "| --- | --- | --- | --- | --- |", *rows])
        + "\n"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--repo", default=str(ROOT), help="repository to clone (default: this checkout's HEAD)"
    )
    parser.add_argument("--whole-job", action="store_true", help="also run the README's whole-job block")
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
