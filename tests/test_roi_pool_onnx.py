"""The export's RoI pooling (a3d.export.roi_pool_onnx): the ONNX graph against torch's roi_align,
the fc6 fold against the unfolded network, max pooling refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from a3d.export.base import ExportError
from a3d.export.roi_pool_onnx import (
    WINDOW_MIN_CHANNELS,
    export_roi_align,
    fold_pool_layout,
    join_maps_by_chunk,
)
from a3d.export.svd import svd_compress
from a3d.runtime.network.roi_order import POOL_CHUNKS
from a3d.train.model.config import NetConfig
from a3d.train.model.net import A3DNet
from a3d.train.model.roi_pool import roi_align


def _rois(count: int, batch: int, height: int, width: int, seed: int) -> torch.Tensor:
    """Boxes in image pixels (stride 16) of every kind: inside, partly and wholly outside the map,
    zero-sized, inverted (x2 < x1), tiny and larger than the image; on random images of the batch."""
    gen = torch.Generator().manual_seed(seed)
    frame = torch.tensor([16.0 * width, 16.0 * height])
    corner = torch.rand(count, 2, generator=gen) * frame * 1.6 - 0.3 * frame
    size = torch.exp(torch.rand(count, 2, generator=gen) * np.log(2 * 16 * max(height, width))) - 1
    boxes = torch.cat([corner, corner + size], dim=1)
    kinds = torch.arange(count) % 5
    boxes[kinds == 1, 2:] = boxes[kinds == 1, :2]  # degenerate: a point
    boxes[kinds == 2, 2] = boxes[kinds == 2, 0] - 40.0  # inverted in x
    boxes[kinds == 3] = torch.tensor([-500.0, -400.0, -300.0, -200.0])  # wholly outside
    image = torch.randint(0, batch, (count, 1), generator=gen).float()
    return torch.cat([image, boxes], dim=1)


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> ort.InferenceSession:
    """The windowed graph (the channel count left dynamic, so the export cannot choose the dense one)."""
    path = tmp_path_factory.mktemp("pool") / "pool.onnx"
    export_roi_align(str(path), torch.zeros(2, 4, 6, 7), _rois(5, 2, 6, 7, seed=0))
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


@pytest.mark.slow
@pytest.mark.parametrize(
    ("batch", "channels", "height", "width", "count"),
    [(2, 8, 9, 11, 300), (2, 3, 14, 18, 37), (1, 16, 27, 36, 500), (2, 5, 4, 3, 1), (1, 4, 9, 11, 0)],
)
def test_exported_pooling_equals_torch(exported, batch, channels, height, width, count) -> None:
    """One export, any batch, channel count, map size and RoI count: the same numbers as training."""
    features = torch.randn(batch, channels, height, width, generator=torch.Generator().manual_seed(count))
    rois = _rois(count, batch, height, width, seed=count + 1)
    got = exported.run(None, {"features": features.numpy(), "rois": rois.numpy()})[0]
    want = roi_align(features, rois).numpy()
    assert got.shape == (count, 7, 7, channels)
    np.testing.assert_allclose(got.transpose(0, 3, 1, 2), want, rtol=0, atol=1e-5)


@pytest.mark.slow
def test_export_pools_on_windows_without_the_dense_intermediate(tmp_path) -> None:
    """The graph is the windowed one: two products per chunk, none of the whole map by all RoIs."""
    path = tmp_path / "pool.onnx"
    export_roi_align(str(path), torch.zeros(1, 4, 6, 7), _rois(5, 1, 6, 7, seed=0))
    ops = [n.op_type for n in onnx.load(str(path)).graph.node]
    assert ops.count("MatMul") == 2 * POOL_CHUNKS
    assert "Transpose" not in ops[-3:]  # the (y, x, C) layout is left for fc6 to absorb


@pytest.mark.slow
def test_few_fixed_channels_pool_as_one_chunk(tmp_path) -> None:
    """Where the export fixes a small channel count the graph pools all RoIs as one chunk (two
    products), with the same numbers."""
    path = tmp_path / "pool.onnx"
    channels = WINDOW_MIN_CHANNELS // 2
    export_roi_align(
        str(path), torch.zeros(1, channels, 6, 7), _rois(5, 1, 6, 7, seed=0), fixed_channels=True
    )
    assert [n.op_type for n in onnx.load(str(path)).graph.node].count("MatMul") == 2
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    features = torch.randn(2, channels, 9, 11, generator=torch.Generator().manual_seed(3))
    rois = _rois(60, 2, 9, 11, seed=4)
    got = session.run(None, {"features": features.numpy(), "rois": rois.numpy()})[0]
    np.testing.assert_allclose(
        got.transpose(0, 3, 1, 2), roi_align(features, rois).numpy(), rtol=0, atol=1e-5
    )


def _outputs(net: A3DNet, seed: int = 0) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(seed)
    color, depth = torch.randn(2, 1, 3, 64, 80, generator=gen) * 50
    rois = torch.cat([torch.zeros(20, 1), torch.rand(20, 2, generator=gen) * 60], 1)
    rois = torch.cat([rois, rois[:, 1:3] + torch.rand(20, 2, generator=gen) * 40], 1)
    context = rois * torch.tensor([1.0, 0.8, 0.8, 1.2, 1.2])
    with torch.no_grad():
        return net(color, depth, rois, context)


@pytest.mark.parametrize(
    "config",
    [
        NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16),
        NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=None),
        NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16, use_context=False, use_depth=False),
    ],
)
@pytest.mark.parametrize("svd", [None, 8])
def test_fold_pool_layout_keeps_the_outputs(config, svd) -> None:
    """The (y, x, c) pooling with fc6's columns permuted answers what the network answers."""
    net = A3DNet(config).eval()
    if svd is not None:
        net, _ = svd_compress(net, svd)
    want = _outputs(net)
    folded = fold_pool_layout(net)
    assert folded.pool_product is not None
    for got, expected in zip(_outputs(folded), want, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)
    assert not torch.equal(_outputs(A3DNet(config).eval())[0], want[0])  # the comparison can fail


def test_max_pool_networks_are_not_folded() -> None:
    """The paper's max RoI pooling stays a training-only ablation: the export refuses it."""
    net = A3DNet(replace(NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16), roi_pool="max"))
    with pytest.raises(ExportError, match="only RoIAlign networks are exported"):
        fold_pool_layout(net)


@pytest.mark.slow
def test_network_exported_on_windows_answers_as_torch(tmp_path, monkeypatch) -> None:
    """The whole runtime graph with windowed pooling (forced for a small network) and fc6 folded:
    ONNX Runtime's outputs are torch's."""
    from a3d.export import roi_pool_onnx
    from a3d.export.onnx_export import RuntimeGraph, example_inputs, export_graph
    from a3d.train.dataset import TargetStats

    monkeypatch.setattr(roi_pool_onnx, "WINDOW_MIN_CHANNELS", 1)
    torch.manual_seed(0)
    net = A3DNet(NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16)).eval()
    graph = RuntimeGraph(net, TargetStats.identity())
    model = export_graph(graph, tmp_path / "raw.onnx")
    assert [n.op_type for n in model.graph.node].count("MatMul") == 2 * 2 * POOL_CHUNKS  # two maps
    session = ort.InferenceSession(str(tmp_path / "raw.onnx"), providers=["CPUExecutionProvider"])
    inputs = example_inputs(96, 128, 150, seed=5)
    got = session.run(
        None, dict(zip(("color", "depth", "rois", "context_rois"), (t.numpy() for t in inputs), strict=True))
    )
    with torch.no_grad():
        want = RuntimeGraph(net, TargetStats.identity())(*inputs)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w.numpy(), rtol=1e-4, atol=1e-5 * float(w.abs().max()) + 1e-7)


def _two_chunked_maps(chunks: tuple[int, int]) -> onnx.ModelProto:
    """Pieces a0.. and b0.. (chunk i: i + 1 rows of (2, 2, 3)), each map's chunks joined, flattened
    to (R, 12), the two maps joined side by side: the shape of fc6's input in the export."""
    helper, value = onnx.helper, onnx.helper.make_tensor_value_info
    inputs, nodes = [], []
    for name, count in zip("ab", chunks, strict=True):
        pieces = [f"{name}{i}" for i in range(count)]
        inputs += [value(p, onnx.TensorProto.FLOAT, [i + 1, 2, 2, 3]) for i, p in enumerate(pieces)]
        nodes.append(helper.make_node("Concat", pieces, [f"{name}_map"], axis=0, name=f"{name}_chunks"))
        nodes.append(
            helper.make_node("Reshape", [f"{name}_map", "rows"], [f"{name}_flat"], name=f"{name}_flat")
        )
    nodes.append(helper.make_node("Concat", ["a_flat", "b_flat"], ["out"], axis=1, name="join"))
    rows = onnx.numpy_helper.from_array(np.array([-1, 12], np.int64), "rows")
    graph = helper.make_graph(nodes, "g", inputs, [value("out", onnx.TensorProto.FLOAT, [None, 24])], [rows])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def _run(model: onnx.ModelProto, feeds: dict[str, np.ndarray]) -> np.ndarray:
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run(None, {i.name: feeds[i.name] for i in session.get_inputs()})[0]


def test_the_maps_are_joined_chunk_by_chunk_with_the_same_rows() -> None:
    rng = np.random.default_rng(0)
    feeds = {
        f"{m}{i}": rng.standard_normal((i + 1, 2, 2, 3)).astype(np.float32) for m in "ab" for i in range(3)
    }
    want = _run(_two_chunked_maps((3, 3)), feeds)
    model = join_maps_by_chunk(_two_chunked_maps((3, 3)))
    onnx.checker.check_model(model)
    makers = {out: n for n in model.graph.node for out in n.output}
    chunks = makers[makers["out"].input[0]]  # out = the rows of one join of the chunks
    assert [makers[i].input for i in chunks.input] == [[f"a{i}", f"b{i}"] for i in range(3)]
    assert [i.name for i in model.graph.initializer] == ["join/row_shape"]  # the old shape is gone
    np.testing.assert_array_equal(_run(model, feeds), want)
    unlike = _two_chunked_maps((3, 2))  # chunks that do not pair up: left as they are
    before = unlike.SerializeToString()
    assert join_maps_by_chunk(unlike).SerializeToString() == before
