"""The bundled samples: the README's main command works on them and finds real objects."""

from __future__ import annotations

import json
import re
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import pytest

from a3d.runtime.cli import eval as eval_cli
from a3d.runtime.cli import run as run_cli
from a3d.runtime.evaluation.metric import EvalConfig, evaluate
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.sources.folder import list_frames
from a3d.runtime.structures.classes import CLASSES
from tests.helpers.samples import SAMPLE_MODEL
from tests.rrd_reader import as_array, read_columns

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
MODEL = SAMPLE_MODEL
MAX_MODEL_BYTES = 25 * 1024 * 1024


def test_bundled_model_is_small_and_self_describing() -> None:
    assert MODEL.stat().st_size <= MAX_MODEL_BYTES
    meta = DetectorModel.load(MODEL).metadata
    assert tuple(meta.classes) == CLASSES
    assert np.all(np.asarray(meta.mean_sizes) > 0)
    assert meta.provenance.get("training_config"), "the bundled model must say how it was trained"
    assert meta.score_calibration is not None, "its scores are the chance a detection is right"


@pytest.fixture(scope="module")
def main_command(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The README's main command on the samples: its detections file and its recording."""
    tmp_path = tmp_path_factory.mktemp("samples")
    out, rrd = tmp_path / "det.jsonl", tmp_path / "samples.rrd"
    assert run_cli.main([str(SAMPLES), "--output", str(out), "--headless", "--save", str(rrd)]) == 0
    return out, rrd


def test_main_command_on_samples_writes_detections_and_a_recording(
    main_command: tuple[Path, Path], tmp_path: Path
) -> None:
    out, rrd = main_command
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


def _pins_not_installed() -> list[str]:
    """ "name==pinned (installed)" for each constraints.txt pin this environment does not have."""
    differ = []
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        name, pinned = line.split("==")
        try:
            installed = version(name)
        except PackageNotFoundError:
            installed = "not installed"
        if installed != pinned:
            differ.append(f"{name}=={pinned} ({installed})")
    return differ


def test_samples_map_equals_the_readmes_under_the_pinned_versions(main_command: tuple[Path, Path]) -> None:
    """The README's samples mAP is what the pinned versions give (other versions move it by ~1 point),
    on a CPU with int8 dot products and on one with AVX2 alone (whose exact int8 kernel the runtime
    asks for: a3d.runtime.network.model.session_options)."""
    differ = _pins_not_installed()
    if differ:
        pytest.skip("installed versions differ from constraints.txt: " + ", ".join(differ))
    readme = (ROOT / "README.md").read_text()
    quoted = re.search(r"([\d.]+) on the samples'\s+(\d+) present classes", readme)
    assert quoted, "README.md no longer quotes the samples' present-class mAP"
    truth, _ = eval_cli.load_truth(SAMPLES)
    detections = {d.frame: d for d in read_detections(main_command[0])}
    result = evaluate(truth, detections, EvalConfig())
    assert sum(c.present for c in result.classes) == int(quoted.group(2))
    assert round(100 * result.map_present(0.25), 1) == pytest.approx(float(quoted.group(1)), abs=0.1)
