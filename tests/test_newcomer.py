"""bench/newcomer.py reads the README's commands as a newcomer would type them."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

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
