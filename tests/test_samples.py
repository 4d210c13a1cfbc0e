"""The bundled samples: the README's main command works on them and finds real objects."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from a3d.runtime.cli import eval as eval_cli
from a3d.runtime.cli import run as run_cli
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.sources.folder import list_frames
from a3d.runtime.structures.classes import CLASSES
from tests.rrd_reader import as_array, read_columns

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
MODEL = SAMPLES / "model.onnx"
MAX_MODEL_BYTES = 25 * 1024 * 1024


def test_bundled_model_is_small_and_self_describing() -> None:
    assert MODEL.stat().st_size <= MAX_MODEL_BYTES
    meta = DetectorModel.load(MODEL).metadata
    assert tuple(meta.classes) == CLASSES
    assert np.all(np.asarray(meta.mean_sizes) > 0)
    assert meta.provenance.get("training_config"), "the bundled model must say how it was trained"


def test_main_command_on_samples_writes_detections_and_a_recording(tmp_path: Path) -> None:
    out, rrd = tmp_path / "det.jsonl", tmp_path / "samples.rrd"
    code = run_cli.main([str(SAMPLES), "--output", str(out), "--headless", "--save", str(rrd)])
    assert code == 0
    lines = read_detections(out)
    assert [d.frame for d in lines] == [ref.name for ref in list_frames(SAMPLES)]
    assert sum(len(d.scores) for d in lines) > 0

    # The .rrd holds the drawn boxes (score >= the view cut) with the JSON's values.
    logged = read_columns(rrd, "/world/detections")
    for index, det in enumerate(lines):
        shown = det.scores >= run_cli.VIEW_MIN_SCORE  # the default view cut
        if not shown.any():
            continue
        boxes = logged[index]
        np.testing.assert_allclose(
            as_array(boxes["Boxes3D:centers"]), det.boxes3d[shown, :3] @ det.R_tilt.T, atol=1e-5
        )
        np.testing.assert_allclose(
            as_array(boxes["Boxes3D:half_sizes"]), det.boxes3d[shown][:, [3, 5, 4]] / 2, atol=1e-5
        )

    # a3d-eval on that output scores real detections: the bundled model finds objects.
    report = tmp_path / "eval"
    assert eval_cli.main([str(SAMPLES), "--detections", str(out), "--out", str(report)]) == 0
    result = json.loads((report / "eval.json").read_text())
    maps = next(iter(result["map"].values()))  # the first threshold, 0.25
    assert maps["present_classes"] > 0.05, result["map"]
    assert (report / "pr_curves.png").stat().st_size > 0
    print(f"samples mAP@0.25 (present classes): {maps['present_classes']:.3f}", file=sys.stderr)
