"""Small ONNX 2D detector files for the tests, one of each layout a3d.runtime.detector2d reads.

Their outputs are constants crafted so that the decoded boxes are known (and, for the boxes layout,
scores that are each channel's mean of the input, which pins its RGB 0..1 convention). The input is
64 x 96 (H x W): a 300 x 150 image is letterboxed into it at scale 0.32.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

INPUT_HW = (64, 96)


def detector_graph(path: Path, input_shape: list[int], outputs: dict[str, np.ndarray | str],
           metadata: dict[str, str] | None = None) -> Path:  # fmt: skip
    """An ONNX file with one float input ``image`` and the given outputs: a constant array, or
    "channel means" (the input's mean per channel, (1, 3) or (3,) as the input is batched or not)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    nodes, infos = [], []
    for name, value in outputs.items():
        if isinstance(value, str):
            axes = [2, 3] if len(input_shape) == 4 else [1, 2]
            nodes.append(helper.make_node("ReduceMean", ["image"], [name], axes=axes, keepdims=0))
            infos.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, input_shape[:-2]))
        else:
            nodes.append(helper.make_node("Constant", [], [name], value=numpy_helper.from_array(value, name)))
            kind = TensorProto.INT64 if value.dtype == np.int64 else TensorProto.FLOAT
            infos.append(helper.make_tensor_value_info(name, kind, list(value.shape)))
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, input_shape)
    model = helper.make_model(
        helper.make_graph(nodes, "detector", [image], infos), opset_imports=[helper.make_opsetid("", 13)]
    )
    model.ir_version = 8
    for key, value in (metadata or {}).items():
        model.metadata_props.add(key=key, value=value)
    onnx.save(model, path)
    return path


def yolox_grid() -> np.ndarray:
    """(1, 126, 8): strides 8, 16, 32 over 64 x 96 (8 x 12 + 4 x 6 + 2 x 3 cells), 3 classes."""
    grid = np.zeros((1, 126, 8), np.float32)
    # stride 8, row 2, column 5: centre (44, 18), size 16 x 12; chair 0.9 x 0.8 = 0.72
    grid[0, 2 * 12 + 5] = [0.5, 0.25, math.log(2), math.log(1.5), 0.9, 0.1, 0.8, 0.1]
    # its neighbour, the same box (x offset -0.5) as chair 0.45: suppressed by NMS
    grid[0, 2 * 12 + 6] = [-0.5, 0.25, math.log(2), math.log(1.5), 0.9, 0.0, 0.5, 0.0]
    # stride 16, row 1, column 2: a cat 0.81, a class the map drops
    grid[0, 96 + 1 * 6 + 2] = [0.5, 0.5, 0.0, 0.0, 0.9, 0.9, 0.0, 0.0]
    # stride 32, row 1, column 2: centre (64, 48), 32 x 48 into the padding; tv 0.6 x 0.5 = 0.3
    grid[0, 120 + 1 * 3 + 2] = [0.0, 0.5, 0.0, math.log(1.5), 0.6, 0.0, 0.0, 0.5]
    grid[0, 0] = [0.5, 0.5, 0.0, 0.0, 0.04, 0.0, 1.0, 0.0]  # a chair below the 0.05 threshold
    return grid


def nanodet_outputs() -> dict[str, np.ndarray]:
    """Per stride a class map and a distance-distribution map over 3 classes (chair, cup, couch):
    one couch 0.7 at stride 16, row 1, column 3 (centre (56, 24)), sides 1, 1, 2, 0.5 strides;
    a cup 0.9 (a class the COCO map drops)."""
    cells = (96, 24, 6)  # strides 8, 16, 32 over 64 x 96
    class_maps = [np.full((1, n, 3), 0.01, np.float32) for n in cells]
    distributions = [np.zeros((1, n, 32), np.float32) for n in cells]
    class_maps[1][0, 1 * 6 + 3, 2] = 0.7  # stride 16, row 1, column 3: a couch, centre (56, 24)
    logits = np.zeros((4, 8), np.float32)
    logits[0, 1] = logits[1, 1] = logits[2, 2] = logits[3, 0] = logits[3, 1] = 30.0  # 1, 1, 2, 0.5 strides
    distributions[1][0, 1 * 6 + 3] = logits.ravel()
    class_maps[0][0, 7, 1] = 0.9  # a cup: dropped by the map
    outputs = {f"cls{i}": m for i, m in enumerate(class_maps)}
    outputs |= {f"reg{i}": m for i, m in enumerate(distributions)}  # after the class maps, as NanoDet's
    return outputs


def boxes_outputs(batched: bool = True) -> dict[str, np.ndarray | str]:
    """boxes / scores / labels over 3 classes (bed, toilet, sink) in a 60 x 40 input: scores are
    the input's R, G and B means."""
    boxes = np.array([[6, 4, 30, 20], [30, 20, 60, 40], [0, 0, 10, 10]], np.float32)
    lead = [1] if batched else []
    return {
        "boxes": boxes.reshape(*lead, 3, 4),
        "scores": "channel means",
        "labels": np.array([0, 1, 2], np.int64).reshape(*lead, 3),
    }
