"""The live front end: a3d-run's cheaper proposal settings for cameras, chosen for live sources."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import pytest

from a3d.runtime.cli import run as run_cli
from a3d.runtime.frontend.depth import fill_depth
from a3d.runtime.frontend.proposals import ProposalConfig, live_proposals, propose
from a3d.runtime.io.detections_io import read_detections
from a3d.runtime.pipeline import PipelineConfig
from a3d.runtime.sources.registry import open_source
from a3d.runtime.structures.geometry import Intrinsics
from tests.helpers.runtime_frames import FakeModel, fake_metadata, write_scene_folder


def test_live_proposals_change_only_the_working_resolution_superpixels_strategies_and_pairs() -> None:
    model = ProposalConfig(max_proposals=321, min_area=150)
    live = live_proposals(model)
    assert (live.scale, live.superpixels.n_segments, live.pairs.parts) == (4, 300, 150)
    assert live.strategies == model.strategies[:6]
    assert (
        replace(live, scale=2, superpixels=model.superpixels, strategies=model.strategies, pairs=model.pairs)
        == model
    )
    few_parts = replace(model, pairs=replace(model.pairs, parts=40))
    assert live_proposals(few_parts).pairs.parts == 40  # never more pair candidates than the model's


def test_front_end_is_a_pipeline_setting_with_a_checked_value() -> None:
    meta = fake_metadata()
    assert PipelineConfig.from_metadata(meta).proposals == meta.proposals
    assert PipelineConfig.from_metadata(meta, front_end="live").proposals == live_proposals(meta.proposals)
    asked = PipelineConfig.from_metadata(meta, front_end="live", max_proposals=900).proposals
    assert asked == replace(live_proposals(meta.proposals), max_proposals=900)  # --max-proposals wins
    with pytest.raises(ValueError, match="front_end"):
        PipelineConfig.from_metadata(meta, front_end="fast")  # type: ignore[arg-type]


class _LiveFolder:
    """A frame folder that says it is a camera (``live = True``), as the RealSense source does."""

    live = True

    def __init__(self, source) -> None:
        self.source = source
        self.incomplete = source.incomplete

    def __iter__(self):
        return iter(self.source)


def _run(argv: list[str]) -> int:
    try:
        return run_cli.main(argv)
    except SystemExit as e:
        return int(e.code or 0)


def test_a3d_run_uses_the_live_front_end_for_live_sources_and_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    model = FakeModel(fake_metadata(proposals=ProposalConfig(max_proposals=200)))
    monkeypatch.setattr(run_cli, "load_model", lambda path, threads: model)
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    common = ["--model", "unused.onnx", "--headless", "--proposals", "compute"]

    def detections(name: str, *flags: str) -> tuple[dict, str]:
        out = tmp_path / f"{name}.jsonl"
        assert _run([str(folder), "--output", str(out), *common, *flags]) == 0
        return {d.frame: d for d in read_detections(out)}, capsys.readouterr().err

    recorded, err = detections("recorded")
    assert run_cli.LIVE_NOTE not in err
    forced, err = detections("forced", "--front-end", "live")
    assert run_cli.LIVE_NOTE not in err  # asked for: nothing to announce
    monkeypatch.setattr(run_cli, "open_source", lambda *a, **k: _LiveFolder(open_source(*a, **k)))
    camera, err = detections("camera")
    assert run_cli.LIVE_NOTE in err
    camera_model, err = detections("camera_model", "--front-end", "model")
    assert run_cli.LIVE_NOTE not in err

    # A live source hands over its newest frame only: compare the frames each run got to.
    assert camera and camera_model and set(camera) | set(camera_model) <= {"a", "b"}

    def same(run: dict, reference: dict) -> bool:
        return all(
            run[n].boxes2d.shape == reference[n].boxes2d.shape
            and (run[n].boxes2d == reference[n].boxes2d).all()
            for n in run
        )

    assert same(camera, forced) and same(camera_model, recorded)
    assert not same(camera, recorded)  # other proposals, other detections


@pytest.mark.slow  # real segmentation of two 480 x 640 frames, several times
def test_live_proposals_cost_under_half_the_models_cpu_time() -> None:
    from a3d.synth.scene import SceneConfig, generate_frame

    scene = SceneConfig(image_size=(480, 640), intrinsics=Intrinsics(525.0, 525.0, 319.5, 239.5))
    frames = [generate_frame(seed, scene) for seed in (910_000, 910_001)]
    inputs = [(f.color[..., ::-1].copy(), fill_depth(f.depth), f.intrinsics) for f in frames]
    model = ProposalConfig(max_proposals=500)

    def cpu_seconds(config: ProposalConfig) -> float:
        best = float("inf")
        for _ in range(3):
            start = time.process_time()
            for color, depth, K in inputs:
                propose(color, depth, K, config)
            best = min(best, time.process_time() - start)
        return best

    propose(*inputs[0], model)  # OpenCV's first Lab conversion builds its tables
    assert cpu_seconds(live_proposals(model)) < 0.5 * cpu_seconds(model)
