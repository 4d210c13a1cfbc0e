"""bench.roi_choice: where a model's 3D boxes are lost, per class."""

from __future__ import annotations

import json
from pathlib import Path

from a3d.synth.cli import main as synth_main
from bench.roi_choice import main, roi_choice


def test_each_class_counts_its_objects_then_the_covered_then_the_reached(tmp_path: Path, capsys) -> None:
    assert synth_main([str(tmp_path / "seq"), "--sequence", "3", "--seed", "3", "--size", "240x320"]) == 0
    frames = tmp_path / "seq" / "frames"
    truth = [json.loads(p.read_text())["objects"] for p in sorted(frames.glob("*.gt.json"))]
    counts = roi_choice(frames, "live")
    assert sum(c["objects"] for c in counts.values()) == sum(len(objects) for objects in truth) > 0
    for c in counts.values():  # a perfect choice among the RoIs finds at least what the top score does
        assert c["objects"] >= c["covered"] >= c["best"] >= c["top"] >= 0
    assert sum(c["covered"] for c in counts.values()) > 0
    capsys.readouterr()
    assert main([str(frames), "--model", "live"]) == 0
    assert "| covered by a RoI |" in capsys.readouterr().out
