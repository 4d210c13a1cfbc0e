"""Unusable model files through the a3d-run command: each is refused with one clear line and exit
status 2 before any frame is read, and no output file is created.

tests/test_model_file.py checks DetectorModel.load's refusals on a hand-built graph; here the
files are damaged copies of a real a3d-export model (tests/conftest.py), run as a user would.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import onnx
import pytest

from a3d.export.onnx_export import save_model
from a3d.runtime import pipeline
from a3d.runtime.cli import run as run_cli
from a3d.runtime.network.model import METADATA_KEY, SCHEMA_VERSION, DetectorModel
from tests.helpers.runtime_frames import write_scene_folder


def _truncated(data: bytes, tmp_path: Path) -> bytes:
    return data[: len(data) // 2]


def _cut_at_the_end(data: bytes, tmp_path: Path) -> bytes:
    return data[:-7]


def _flipped_weight(data: bytes, tmp_path: Path) -> bytes:
    """One byte flipped inside the largest weight tensor: still a valid protobuf that loads."""
    model = onnx.load_from_string(data)
    weights = max(model.graph.initializer, key=lambda t: len(t.raw_data)).raw_data
    at = data.index(weights) + len(weights) // 2
    return data[:at] + bytes([data[at] ^ 0x40]) + data[at + 1 :]


def _edited_metadata(edit: Callable[[dict], str]) -> Callable[[bytes, Path], bytes]:
    def damage(data: bytes, tmp_path: Path) -> bytes:
        model = onnx.load_from_string(data)
        entry = next(p for p in model.metadata_props if p.key == METADATA_KEY)
        entry.value = edit(json.loads(entry.value))
        return model.SerializeToString()

    return damage


def _no_metadata(data: bytes, tmp_path: Path) -> bytes:
    model = onnx.load_from_string(data)
    del model.metadata_props[:]
    return model.SerializeToString()


def _renamed_input(data: bytes, tmp_path: Path) -> bytes:
    """The graph's "color" input renamed to "image", saved with a3d metadata (and checksum) as
    a3d-export would: a file that is whole and consistent, for another contract."""
    model = onnx.load_from_string(data)
    metadata = DetectorModel.load(tmp_path / "model.onnx", threads=1).metadata
    for node in model.graph.node:
        node.input[:] = ["image" if name == "color" else name for name in node.input]
    model.graph.input[0].name = "image"
    save_model(model, metadata, tmp_path / "renamed.onnx")
    return (tmp_path / "renamed.onnx").read_bytes()


def _newer(meta: dict) -> str:
    return json.dumps({**meta, "schema_version": SCHEMA_VERSION + 1, "a_new_field": [1, 2]})


def _proposal_setting(path: str, value: object) -> Callable[[dict], str]:
    """Set proposals.PATH (dotted) to value in the metadata."""

    def edit(meta: dict) -> str:
        *parents, leaf = path.split(".")
        node = meta["proposals"]
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
        return json.dumps(meta)

    return edit


CASES = {
    "truncated": (_truncated, "truncated or corrupted ONNX file"),
    "cut_at_the_end": (_cut_at_the_end, "truncated or corrupted ONNX file"),
    "corrupted": (_flipped_weight, "corrupted model file (graph and weights fail the metadata checksum)"),
    "no_metadata": (_no_metadata, "an ONNX model without a3d metadata"),
    "newer_schema": (
        _edited_metadata(_newer),
        f"schema version {SCHEMA_VERSION + 1} is newer than this runtime's",
    ),
    "inputs": (_renamed_input, "model inputs image float[1,3,?,?], depth"),
    "deep_json": (_edited_metadata(lambda meta: "[" * 100_000), "a3d metadata unreadable JSON"),
    "huge_number": (
        _edited_metadata(lambda meta: json.dumps(meta).replace('"nms_iou": 0.3', '"nms_iou": 1' + "0" * 400)),
        "a3d metadata nms_iou must be a finite number",
    ),
    "proposal_setting_type": (
        _edited_metadata(_proposal_setting("superpixels.n_segments", "many")),
        "a3d metadata proposals.superpixels.n_segments must be an integer in [1, 10000000], got 'many'",
    ),
    "proposal_count_huge": (
        _edited_metadata(_proposal_setting("max_proposals", 10**30)),
        "a3d metadata proposals.max_proposals must be an integer in [1, 10000000]",
    ),
    "detector_not_a_name": (
        _edited_metadata(lambda meta: json.dumps({**meta, "detector": 3})),
        "a3d metadata detector must be a name or null, got 3",
    ),
    "proposal_weights_short": (
        _edited_metadata(_proposal_setting("edge_weights", [1.0, 2.0])),
        "a3d metadata proposals.edge_weights must be a list of 3 values",
    ),
}


@pytest.mark.slow  # the exported tiny model (conftest)
@pytest.mark.parametrize("case", list(CASES))
def test_unusable_model_is_refused_before_any_frame(
    case: str,
    tmp_path: Path,
    tiny_model: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    damage, says = CASES[case]
    (tmp_path / "model.onnx").write_bytes(tiny_model.read_bytes())
    path = tmp_path / f"{case}.onnx"
    path.write_bytes(damage(tiny_model.read_bytes(), tmp_path))
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    read: list[object] = []
    monkeypatch.setattr(pipeline, "load_and_prepare", lambda *args: read.append(args))
    output = tmp_path / "out" / "detections.jsonl"

    status = run_cli.main([str(folder), "--model", str(path), "--output", str(output), "--headless"])

    err = capsys.readouterr().err
    assert status == 2 and not read and not output.exists() and not output.parent.exists()
    assert err.count("\n") == 1 and err.startswith(f"a3d-run: error: {path}: ") and says in err, err


@pytest.mark.slow  # the exported tiny model (conftest)
def test_the_undamaged_model_runs(tmp_path: Path, tiny_model: Path, capsys: pytest.CaptureFixture) -> None:
    """The control for the cases above: the same command with the intact file writes both frames."""
    folder = write_scene_folder(tmp_path / "frames", ["a", "b"])
    output = tmp_path / "out" / "detections.jsonl"
    assert run_cli.main([str(folder), "--model", str(tiny_model), "--output", str(output), "--headless"]) == 0
    lines = [json.loads(line) for line in output.read_text().splitlines()]
    assert [line["frame"] for line in lines] == ["a", "b"]
    assert all(np.isfinite(d["score"]) for line in lines for d in line["detections"])
