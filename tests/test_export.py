"""a3d-export: a tiny trained checkpoint -> model.onnx that the runtime loads and that matches torch.

Two exports (the dynamo exporter takes ~10 s CPU each): a float32 model verified on real frames,
and an SVD (rank 8) + int8 model calibrated on the same frames, its RoI pooling exported on
windows (a3d.export.roi_pool_onnx, forced for this small network). The reference everywhere is the
eager checkpoint network with the softmax and the TargetStats de-normalisation applied outside
it (a3d.train.inference.TorchNetwork), so the folded statistics are checked, not assumed.
"""

from __future__ import annotations

import contextlib
import io
import json
import shlex
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import onnx
import pytest
import torch

from a3d.export import build, cli, roi_pool_onnx
from a3d.export.quantize import MOVES, producer_through
from a3d.export.svd import svd_compress
from a3d.export.verify import folder_inputs
from a3d.runtime.cli import run as run_cli
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.network.roi_order import POOL_CHUNKS
from a3d.runtime.pipeline import PipelineConfig
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.viewer.options import viewer_requested
from a3d.train.checkpoint import load_checkpoint, load_trained, save_checkpoint
from a3d.train.config import TrainConfig
from a3d.train.dataset import TargetStats
from a3d.train.inference import TorchNetwork
from a3d.train.model import A3DNet
from tests.helpers.synth_frames import write_synth_frames

# slow: two ONNX exports (dynamo) and an int8 calibration
pytestmark = [
    pytest.mark.slow,
    pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning"),
]
SVD_RANK = 8
CONFIG = {
    "net": {"width": 0.125, "fuse_channels": 32, "fc6": 64, "fc7": 48, "trunk_norm": True},
    "data": {"input_scale": 0.75},
    "proposals": {"min_area": 20, "max_proposals": 150},
    "inference": {"top_k": 50, "nms_iou": 0.4, "min_score": 0.02},
}


def _checkpoint(path: Path, rng: np.random.Generator, stats: TargetStats | None = None) -> None:
    """A checkpoint as a3d.train.loop writes it, with non-trivial BatchNorms (trunks and head), heads
    and target stats."""
    config = TrainConfig.from_dict(CONFIG)
    torch.manual_seed(0)
    net = A3DNet(config.net).eval()
    with torch.no_grad():
        trunk_norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
        assert len(trunk_norms) == 26  # exported folded into the convs
        for bn in (net.bn6, net.bn7, *trunk_norms):
            bn.running_mean.normal_(0, 0.1)
            bn.running_var.uniform_(0.5, 2.0)
            bn.weight.uniform_(0.5, 1.5)
        for head in (net.cls_score, net.bbox_pred_3d, net.bbox_pred_2d):
            head.weight.normal_(0, 0.3)
            head.bias.normal_(0, 0.1)
    stats = stats or TargetStats(rng.normal(0, 0.3, (20, 7)), rng.uniform(0.05, 0.5, (20, 7)),
                                 rng.normal(0, 0.1, (20, 4)), rng.uniform(0.05, 0.3, (20, 4)))  # fmt: skip
    save_checkpoint(path, {
        "iteration": 5, "config": config.to_json(), "model": net.state_dict(), "optimizer": {},
        "target_stats": stats.to_tensors(), "mean_sizes": torch.from_numpy(rng.uniform(0.3, 2.0, (19, 3))),
        "classes": list(CLASSES),
    })  # fmt: skip


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory):
    """The checkpoint, frames, and both exports (float32; svd + int8) with their CLI output."""
    root = tmp_path_factory.mktemp("export")
    rng = np.random.default_rng(0)
    frames = write_synth_frames(root / "synth", 3)
    _checkpoint(root / "run" / "checkpoint.pt", rng)
    (root / "run" / "metrics.jsonl").write_text('{"kind": "data", "iter": 0, "frames": 3, "rois": 500}\n')
    results, stdout = {}, {}
    for name, extra in (
        ("float", ["--verify-frames", str(frames)]),
        ("int8", ["--svd", str(SVD_RANK), "--int8", "--calib", str(frames),
                  "--verify-frames", str(frames)]),
    ):  # fmt: skip
        out = root / f"{name}.onnx"
        with contextlib.redirect_stdout(io.StringIO()) as printed, pytest.MonkeyPatch.context() as patch:
            if name == "int8":  # this small network's pooling exported on windows (roi_pool_onnx), quantised
                patch.setattr(roi_pool_onnx, "WINDOW_MIN_CHANNELS", 1)
            assert cli.main([str(root / "run" / "checkpoint.pt"), "-o", str(out), *extra]) == 0
        results[name], stdout[name] = out, printed.getvalue()
    return SimpleNamespace(checkpoint=root / "run" / "checkpoint.pt", frames=frames, stdout=stdout, **results)


def _reference(checkpoint: Path, net=None) -> TorchNetwork:
    trained = load_trained(checkpoint)
    return TorchNetwork(net if net is not None else trained.net, trained.stats)


def test_float_model_passes_the_checker_and_the_runtime_loads_it(run) -> None:
    model = onnx.load(str(run.float))
    onnx.checker.check_model(model, full_check=True)
    assert model.ir_version <= 13 and {(o.domain, o.version) for o in model.opset_import} == {("", 18)}
    dims = [d.dim_param for d in model.graph.input[0].type.tensor_type.shape.dim[2:]]
    assert dims == ["height", "width"] and model.graph.input[2].type.tensor_type.shape.dim[0].dim_param
    assert {n.op_type for n in model.graph.node}.isdisjoint({"BatchNormalization", "Dropout"})
    loaded = DetectorModel.load(run.float, threads=1)
    assert loaded.metadata.content_sha256 and loaded.metadata.provenance["export"]["opset"] == 18


def test_metadata_comes_from_the_checkpoint(run) -> None:
    meta = DetectorModel.load(run.float, threads=1).metadata
    state = torch.load(run.checkpoint, weights_only=True)
    config = TrainConfig.from_json(state["config"])
    np.testing.assert_array_equal(meta.mean_sizes, state["mean_sizes"].numpy())
    assert meta.classes == CLASSES and meta.input_scale == 0.75 and meta.context_scale == 1.5
    assert (meta.top_k, meta.nms_iou, meta.min_score) == (50, 0.4, 0.02)
    assert meta.proposals.max_proposals == 150 and meta.depth_truncation_m == 10.0
    # The runtime rebuilds the very proposal configuration the network was trained with.
    assert PipelineConfig.from_metadata(meta).proposals == config.proposals
    prov = meta.provenance
    assert prov["checkpoint"]["iteration"] == 5 and len(prov["checkpoint"]["sha256"]) == 64
    assert prov["training_config"] == json.loads(state["config"])
    assert prov["training_data"] == {"frames": 3, "rois": 500}
    assert prov["a3d_version"] and prov["export"]["torch"] and prov["exported_at"]
    assert prov["verification"]["inputs"] == ["synth_000000", "synth_000001"]
    assert prov["verification"]["float32_vs_torch"]["probs"]["max_abs"] <= 1e-4


@pytest.mark.parametrize("count", [1, 37])
def test_onnx_runtime_matches_torch_with_the_statistics_folded_in(run, count: int) -> None:
    model = DetectorModel.load(run.float, threads=1)
    reference = _reference(run.checkpoint)
    item = next(folder_inputs(run.frames, PipelineConfig.from_metadata(model.metadata), 1))
    assert len(item.rois) >= count
    feeds = (item.color, item.depth, item.rois[:count], item.context_rois[:count])
    probs, deltas3d, deltas2d = model.run(*feeds)
    want = reference.run(*feeds)
    assert (
        probs.shape == (count, 20) and deltas3d.shape == (count, 20, 7) and deltas2d.shape == (count, 20, 4)
    )
    np.testing.assert_allclose(probs, want[0], rtol=0, atol=1e-4)
    assert probs.max(1).min() < 0.99  # not a comparison of saturated softmaxes
    for got, ref in ((deltas3d, want[1]), (deltas2d, want[2])):
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4 * np.abs(ref).max())
    # The fold matters: the network's own (normalised) deltas are far from the raw ones.
    stats = load_trained(run.checkpoint).stats
    normalised3d = (want[1] - stats.mean3d) / stats.std3d
    assert np.abs(normalised3d - deltas3d).max() > 1000 * 1e-4 * np.abs(want[1]).max()


def test_svd_at_full_rank_reproduces_the_network_and_low_rank_does_not(run) -> None:
    trained = load_trained(run.checkpoint)
    item = next(folder_inputs(run.frames, trained.config.pipeline(np.ones((19, 3))), 1))
    feeds = (item.color, item.depth, item.rois, item.context_rois)
    want = TorchNetwork(trained.net, trained.stats).run(*feeds)
    full, summary = svd_compress(trained.net, 64)  # fc6 is 64 x 3136 (full rank 64), fc7 48 x 64 (48)
    assert [summary[k]["rank"] for k in ("fc6", "fc7")] == [64, 48]
    assert summary["fc6"]["energy_kept"] == pytest.approx(1.0)
    got = TorchNetwork(full, trained.stats).run(*feeds)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-4)
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-4, atol=1e-4 * np.abs(w).max())
    low, _ = svd_compress(trained.net, 2)
    low_deltas = TorchNetwork(low, trained.stats).run(*feeds)[1]
    assert np.abs(low_deltas - want[1]).max() > 1e-2 * np.abs(want[1]).max()
    with pytest.raises(ValueError, match="rank must be a positive integer"):
        svd_compress(trained.net, 0)


def test_svd_int8_export_is_quantized_loads_and_stays_close(run) -> None:
    model = onnx.load(str(run.int8))
    ops = {n.op_type for n in model.graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops or ops & {"QLinearConv", "QLinearMatMul"}
    assert sum(n.op_type == "Gemm" for n in model.graph.node) >= 5  # fc6 and fc7 are two Gemms each
    windows = [n for n in model.graph.node if n.op_type == "MatMul"]
    assert len(windows) == 2 * 2 * POOL_CHUNKS  # both maps' window products, kept float
    # fc6's input quantisation moved up to each chunk's product: the pieces are joined as bytes,
    # each chunk's two maps side by side (join_maps_by_chunk), then the chunks
    (joined,) = [n for n in model.graph.node if n.op_type == "Concat" and len(n.input) == POOL_CHUNKS]
    makers = {out: n for n in model.graph.node for out in n.output}
    pairs = [makers[i] for i in joined.input]
    assert all(p.op_type == "Concat" and len(p.input) == 2 for p in pairs)
    pieces = [makers[i] for p in pairs for i in p.input]
    assert all(q.op_type == "QuantizeLinear" and makers[q.input[0]].op_type == "MatMul" for q in pieces)
    # each chunk's row product reads its bilinear weights as bytes (an integer product on the map's
    # bytes in ONNX Runtime), its column product float rows
    as_bytes = [n for n in windows if makers[n.input[0]].op_type == "DequantizeLinear"]
    assert len(as_bytes) == 2 * POOL_CHUNKS
    # ... and each map through an exact int8 copy (int8 windows where the CPU adds them exactly)
    maps = {(m := producer_through(makers, n.input[1], MOVES)).name: m for n in as_bytes}.values()
    int8_zero = {
        t.name for t in model.graph.initializer if t.data_type == onnx.TensorProto.INT8 and not t.dims
    }
    assert len(maps) == 2 and all(m.input[2] in int8_zero for m in maps)
    loaded = DetectorModel.load(run.int8, threads=1)
    assert loaded.metadata.pool_chunks == POOL_CHUNKS  # the runtime orders the RoIs for the chunks
    verification = loaded.metadata.provenance["verification"]
    # The float SVD export matched its own torch model; rank 8 changed the network measurably.
    assert verification["float32_vs_torch"]["deltas3d"]["rel"] <= 1e-4
    assert verification["float32_vs_uncompressed"]["deltas3d"]["rel"] > 1e-2
    assert loaded.metadata.provenance["export"]["calibration"]["frames"] == 3
    trained = load_trained(run.checkpoint)
    svd_net, _ = svd_compress(trained.net, SVD_RANK)
    item = next(folder_inputs(run.frames, PipelineConfig.from_metadata(loaded.metadata), 1))
    feeds = (item.color, item.depth, item.rois, item.context_rois)
    got = loaded.run(*feeds)
    want = TorchNetwork(svd_net, trained.stats).run(*feeds)
    assert all(np.isfinite(g).all() for g in got)
    probs_error = np.abs(got[0] - want[0]).max()
    deltas_error = np.abs(got[1] - want[1]).max() / np.abs(want[1]).max()
    assert 1e-5 < probs_error < 0.02 and deltas_error < 0.15  # quantised (not float), but close


def test_int8_convolutions_write_their_relu_outputs_directly(run) -> None:
    """A ReLU after a quantised product is folded into its output's quantisation (zero point 0):
    no float round trip of the activations (DequantizeLinear -> Relu -> QuantizeLinear) is left."""
    graph = onnx.load(str(run.int8)).graph
    assert not any(n.op_type == "Relu" for n in graph.node)
    zero_points = {t.name: onnx.numpy_helper.to_array(t) for t in graph.initializer}
    convs = [n for n in graph.node if n.op_type == "Conv"]
    assert convs
    for conv in convs:
        (quantize,) = [n for n in graph.node if conv.output[0] in n.input]
        assert quantize.op_type == "QuantizeLinear"  # straight to the next layer's int8 input
        assert int(zero_points[quantize.input[2]]) == 0  # its range starts at 0: the ReLU clamps there


def test_cli_prints_the_run_command_and_refuses_bad_usage(run, capsys, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main([str(run.checkpoint), "-o", str(tmp_path / "m.onnx"), "--int8"])
    assert info.value.code == 2
    assert cli.main([str(tmp_path / "absent.pt"), "-o", str(tmp_path / "m.onnx")]) == 2
    assert "absent.pt: no such checkpoint file" in capsys.readouterr().err
    assert cli.main([str(run.checkpoint), "-o", str(tmp_path / "m.onnx"), "--svd", "0"]) == 2
    assert "--svd 0: the rank must be a positive integer" in capsys.readouterr().err
    assert not (tmp_path / "m.onnx").exists()
    absent = [str(run.checkpoint), "-o", str(tmp_path / "m.onnx"), "--score-calibration", "absent"]
    assert cli.main(absent) == 2  # a missing folder: one line, without argparse's usage
    assert capsys.readouterr().err == "a3d-export: error: --score-calibration absent: no such folder\n"
    command = run.stdout["float"].strip().splitlines()[-1]
    assert command.startswith("a3d-run FRAMES --model ") and str(run.float.resolve()) in command
    suggested = run_cli.build_parser().parse_args(shlex.split(command)[1:])
    assert not viewer_requested(suggested)  # runs on a machine without a display


def test_a_score_calibration_that_cannot_be_fitted_writes_nothing(run, capsys, tmp_path: Path) -> None:
    """The random network gets no detection right on the frames: nothing says where 0.5 lies.
    (The fit itself, on the bundled model: tests/test_score_calibration.py.)"""
    out = tmp_path / "calibrated.onnx"
    assert cli.main([str(run.checkpoint), "-o", str(out), "--score-calibration", str(run.frames)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"a3d-export: error: {run.frames}: cannot fit the score calibration: ")
    assert "0 right: need both right and wrong ones" in err and not out.exists()


def test_max_roi_pooling_networks_are_refused(run, capsys, tmp_path: Path) -> None:
    """net.roi_pool=max is the training-only ablation of the paper's pooling: not exported."""
    state = load_checkpoint(run.checkpoint)
    config = TrainConfig.from_json(state["config"], "fixture")
    state["config"] = replace(config, net=replace(config.net, roi_pool="max")).to_json()
    save_checkpoint(tmp_path / "max.pt", state)
    assert cli.main([str(tmp_path / "max.pt"), "-o", str(tmp_path / "m.onnx")]) == 2
    assert "max.pt: network uses 'max' RoI pooling" in capsys.readouterr().err
    assert not (tmp_path / "m.onnx").exists()


def test_a_graph_unlike_torch_fails_verification_and_writes_nothing(
    run, monkeypatch, capsys, tmp_path
) -> None:
    """The float export of the fixture checkpoint, checked against a checkpoint with other
    target statistics: the folded statistics no longer match, exit code 1, no file."""
    other = tmp_path / "run" / "checkpoint.pt"
    _checkpoint(other, np.random.default_rng(5))  # other random target statistics

    def stale_export(graph, path, opset):
        model = onnx.load(str(run.float))
        del model.metadata_props[:]
        onnx.save(model, str(path))
        return model

    monkeypatch.setattr(build, "export_graph", stale_export)
    out = tmp_path / "model.onnx"
    assert cli.main([str(other), "-o", str(out), "--verify-frames", str(run.frames)]) == 1
    err = capsys.readouterr().err
    assert "verification failed" in err and "nothing written" in err and not out.exists()


def test_a3d_run_on_samples_equals_the_pure_torch_reference(run, tmp_path: Path) -> None:
    """The product path (a3d-export -> a3d-run, ONNX Runtime) and the eager checkpoint
    (a3d.train.inference.TorchDetector) give the same detections on the bundled samples."""
    from a3d.runtime.io.detections_io import read_detections
    from a3d.runtime.sources.folder import FolderSource
    from a3d.train.inference import TorchDetector

    samples = Path(__file__).resolve().parents[1] / "samples"
    out = tmp_path / "det.jsonl"
    assert run_cli.main([str(samples), "--model", str(run.float), "--output", str(out), "--headless"]) == 0
    onnx_side = {d.frame: d for d in read_detections(out)}
    source = FolderSource(samples)
    refs = source.refs[:3]
    reference = TorchDetector.from_checkpoint(run.checkpoint)
    torch_side = {ref.name: reference.detect(source.read(ref)) for ref in refs}
    total = 0
    for ref in refs:
        a, b = onnx_side[ref.name], torch_side[ref.name]
        total += len(b.scores)
        # Same detections: (class, proposal box) pairs, then equal scores and decoded boxes.
        key_a = {
            (int(c), *np.round(box, 2)): i
            for i, (c, box) in enumerate(zip(a.class_ids, a.boxes2d, strict=True))
        }
        key_b = {
            (int(c), *np.round(box, 2)): i
            for i, (c, box) in enumerate(zip(b.class_ids, b.boxes2d, strict=True))
        }
        assert key_a.keys() == key_b.keys(), ref.name
        ia = np.array([key_a[k] for k in key_b])
        ib = np.array(list(key_b.values()))
        np.testing.assert_allclose(a.scores[ia], b.scores[ib], atol=1e-4)
        np.testing.assert_allclose(a.boxes3d[ia], b.boxes3d[ib], rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(a.R_tilt, b.R_tilt, atol=1e-12)
    assert total > 20  # a real comparison, not two empty lists
