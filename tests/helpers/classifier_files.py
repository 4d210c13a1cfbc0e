"""Small ONNX image classifiers for the tests: (N, 3, H, W) -> per-channel means -> (N, L) softmax.

The logits are ``means @ weights + bias``: with zero weights every crop gets softmax(bias), a
constant the tests can predict; with weights, the crop's colour picks the class, which pins the
classifier's RGB order and its ``(value - 128) / 128`` input.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def classifier_graph(path: Path, labels: list[str], weights: np.ndarray, bias: np.ndarray,
                     input_shape: tuple = ("batch", 3, "height", "width")) -> Path:  # fmt: skip
    """An ONNX file ``path``: the ``labels`` (metadata, a line each), ``weights`` (3, L), ``bias`` (L,)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    batch = input_shape[0]
    nodes = [
        helper.make_node("ReduceMean", ["image"], ["means"], axes=[2, 3], keepdims=0),
        helper.make_node("MatMul", ["means", "weights"], ["mixed"]),
        helper.make_node("Add", ["mixed", "bias"], ["logits"]),
        helper.make_node("Softmax", ["logits"], ["probs"], axis=-1),
    ]
    inits = [numpy_helper.from_array(np.asarray(weights, np.float32), "weights"),
             numpy_helper.from_array(np.asarray(bias, np.float32), "bias")]  # fmt: skip
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, list(input_shape))
    probs = helper.make_tensor_value_info("probs", TensorProto.FLOAT, [batch, len(labels)])
    model = helper.make_model(
        helper.make_graph(nodes, "classifier", [image], [probs], inits),
        opset_imports=[helper.make_opsetid("", 13)],
    )
    model.ir_version = 8
    model.metadata_props.add(key="labels", value="\n".join(labels))
    onnx.save(model, path)
    return path


def constant_classifier(path: Path, labels: list[str], probs: list[float], **kwargs) -> Path:
    """A classifier that gives every crop the probabilities ``probs``."""
    return classifier_graph(path, labels, np.zeros((3, len(labels))), np.log(probs), **kwargs)
