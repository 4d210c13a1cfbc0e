"""A3DNet exports to ONNX (torch.onnx dynamo exporter) and ONNX Runtime CPU reproduces torch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from a3d.train.model.config import NetConfig
from a3d.train.model.net import A3DNet

INPUTS = ("color", "depth", "rois", "context_rois")
OUTPUTS = ("class_logits", "deltas3d", "deltas2d")
# slow: an ONNX export (dynamo)
pytestmark = [
    pytest.mark.slow,
    pytest.mark.filterwarnings("ignore::FutureWarning", "ignore:.*axis name.*:UserWarning"),
]


def _rois(count: int, gen: torch.Generator, height: int, width: int) -> torch.Tensor:
    """Random boxes on image 0, some reaching past the border."""
    corner = torch.rand(count, 2, generator=gen) * torch.tensor([width + 20.0, height + 20.0]) - 10
    size = torch.rand(count, 2, generator=gen) * torch.tensor([width / 1.5, height / 1.5]) + 1
    return torch.cat([torch.zeros(count, 1), corner, corner + size], dim=1)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[A3DNet, Path]:
    torch.manual_seed(0)
    net = A3DNet(NetConfig(width=0.125, fc6=64, fc7=48, fuse_channels=32)).eval()
    with torch.no_grad():  # non-trivial BatchNorm statistics and heads, so folding them is checked
        for bn in (net.bn6, net.bn7):
            bn.running_mean.normal_(0, 0.1)
            bn.running_var.uniform_(0.5, 2.0)
            bn.weight.uniform_(0.5, 1.5)
        for head in (net.cls_score, net.bbox_pred_3d, net.bbox_pred_2d):
            head.weight.normal_(0, 0.3)
    gen = torch.Generator().manual_seed(1)
    # Distinct example tensors: the exporter merges inputs given as one aliased tensor (then the
    # graph would silently read the colour image for depth too).
    example = (torch.randn(1, 3, 64, 80, generator=gen), torch.randn(1, 3, 64, 80, generator=gen),
               _rois(5, gen, 64, 80), _rois(5, gen, 64, 80))  # fmt: skip
    count = torch.export.Dim("rois")
    path = tmp_path_factory.mktemp("onnx") / "a3d.onnx"
    torch.onnx.export(
        net,
        example,
        path,
        input_names=list(INPUTS),
        output_names=list(OUTPUTS),
        dynamic_shapes={"color": None, "depth": None, "rois": {0: count}, "context_rois": {0: count}},
        dynamo=True,
        external_data=False,
        verbose=False,
    )
    return net, path


def test_graph_is_plain_onnx_for_onnxruntime(exported: tuple[A3DNet, Path]) -> None:
    model = onnx.load(exported[1])
    onnx.checker.check_model(model)
    assert model.ir_version <= 13  # ORT 1.31's limit (docs/platform.md)
    assert {o.domain for o in model.opset_import} <= {"", "ai.onnx"}
    assert [i.name for i in model.graph.input] == list(INPUTS)
    assert [o.name for o in model.graph.output] == list(OUTPUTS)
    roi_dim = model.graph.input[2].type.tensor_type.shape.dim[0]
    assert roi_dim.dim_param and not roi_dim.HasField("dim_value")  # the RoI count is dynamic
    assert not {n.op_type for n in model.graph.node} & {"BatchNormalization", "Dropout"}


@pytest.mark.parametrize("count", [3, 41])
def test_onnxruntime_matches_torch(exported: tuple[A3DNet, Path], count: int) -> None:
    net, path = exported
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    gen = torch.Generator().manual_seed(count)
    color, depth = torch.randn(1, 3, 64, 80, generator=gen), torch.randn(1, 3, 64, 80, generator=gen)
    rois, context = _rois(count, gen, 64, 80), _rois(count, gen, 64, 80)
    feeds = dict(zip(INPUTS, (t.numpy() for t in (color, depth, rois, context)), strict=True))
    logits, deltas3d, deltas2d = session.run(list(OUTPUTS), feeds)
    with torch.no_grad():
        want = [t.numpy() for t in net(color, depth, rois, context)]
    assert logits.shape == (count, 20) and deltas3d.shape == (count, 140) and deltas2d.shape == (count, 80)
    probabilities = torch.softmax(torch.from_numpy(logits), 1).numpy()
    np.testing.assert_allclose(probabilities, torch.softmax(torch.from_numpy(want[0]), 1).numpy(), atol=1e-4)
    assert probabilities.max(1).min() < 0.99  # the comparison is not between saturated softmaxes
    np.testing.assert_allclose(deltas3d, want[1], rtol=1e-4, atol=1e-4 * np.abs(want[1]).max())
    np.testing.assert_allclose(deltas2d, want[2], rtol=1e-4, atol=1e-4 * np.abs(want[2]).max())
