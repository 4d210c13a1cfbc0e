"""The bundled models by short name (a3d.runtime.models): a3d-run --model NAME, its default, the
model card (--model-info), Detector.load()."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from a3d.runtime import Detector
from a3d.runtime.cli import run as run_cli
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.models import DEFAULT_MODEL, MODELS, PIPELINE_DETECTORS, is_model_name, model_path
from a3d.runtime.network.model import DetectorModel
from tests.helpers.samples import SAMPLES


def test_every_short_name_is_a_bundled_self_describing_model() -> None:
    assert DEFAULT_MODEL in MODELS and model_path() == model_path(DEFAULT_MODEL)
    for name in MODELS:
        assert is_model_name(name) and model_path(name).is_file()
        meta = DetectorModel.load(model_path(name), threads=1).metadata
        assert meta.provenance.get("training_config") and meta.score_calibration is not None
    assert model_path("some/model.onnx") == Path("some/model.onnx") and not is_model_name("some/model.onnx")
    assert model_path(Path(DEFAULT_MODEL)) == model_path()  # a name typed where a path goes (argparse)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_model_info_prints_the_card(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        run_cli.main(["--model-info", name])
    assert done.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"model: {model_path(name)} (")
    assert any(line.startswith("network: colour trunk VGG16 x ") for line in lines)
    assert any(line.startswith("scores: calibrated on ") for line in lines)
    licence = next(i for i, line in enumerate(lines) if line.startswith("weights licence: "))
    detector = PIPELINE_DETECTORS.get(name)
    if detector is None:
        assert licence == len(lines) - 1
    else:  # a pipeline's card ends with its 2D detector's: what it is, its training data, its licence
        assert lines[licence + 1].startswith(f"2D detector: {detector}: ") and "COCO" in lines[licence + 1]
        assert lines[licence + 2].startswith("2D detector licence: Apache-2.0")


def test_model_info_of_no_model_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        run_cli.main(["--model-info", str(tmp_path / "none.onnx")])
    assert done.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"a3d-run: error: {tmp_path / 'none.onnx'}: no such model file"]


def test_a_folder_without_a_model_runs_the_default_and_a_name_picks_one(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for path in [SAMPLES / "intrinsics.json", *SAMPLES.glob("synth_000000.*")]:
        shutil.copy(path, folder / path.name)
    default, named = tmp_path / "default.jsonl", tmp_path / "named.jsonl"
    assert run_cli.main([str(folder), "--output", str(default), "--headless"]) == 0
    assert run_cli.main([str(folder), "--model", DEFAULT_MODEL, "--output", str(named), "--headless"]) == 0
    (a,), (b,) = read_detections(default), read_detections(named)
    assert len(a.scores) > 0 and a.scores.tolist() == b.scores.tolist()
    direct = Detector.load()  # the Python API's default is the same model
    assert (
        direct.model.metadata.content_sha256
        == DetectorModel.load(model_path(), threads=1).metadata.content_sha256
    )


def test_the_default_pipeline_brings_its_2d_detector_and_live_runs_alone() -> None:
    assert DEFAULT_MODEL == "real" and PIPELINE_DETECTORS["real"] == "yolox-nano"
    default = Detector.load(threads=1)
    assert default.config.detector is not None and default.config.detector.name == "yolox-nano"
    assert Detector.load("live", threads=1).config.detector is None
    assert Detector.load("real", threads=1, detector="none").config.detector is None


def test_a_model_file_that_names_its_2d_detector_runs_with_it(tmp_path: Path) -> None:
    """a3d-finetune's models name their base pipeline's detector (metadata ``detector``, schema 5):
    running the file runs that pipeline, "none" still turns it off; a bundled schema-4 file names none."""
    import dataclasses

    import onnx

    from a3d.export.onnx_export import save_model
    from a3d.runtime.models import pipeline_detector

    live = DetectorModel.load(model_path("live"), threads=1).metadata
    assert live.detector is None and pipeline_detector("live", None, live.detector) is None
    mine = tmp_path / "mine.onnx"
    save_model(onnx.load(str(model_path("live"))), dataclasses.replace(live, detector="yolox-nano"), mine)
    assert DetectorModel.load(mine, threads=1).metadata.detector == "yolox-nano"
    assert Detector.load(mine, threads=1).config.detector.name == "yolox-nano"
    assert Detector.load(mine, threads=1, detector="none").config.detector is None
    assert pipeline_detector("real", None, None) == "yolox-nano"  # a bundled pipeline's own comes first
    assert pipeline_detector(mine, "my.onnx", "yolox-nano") == "my.onnx"  # and --detector before both
