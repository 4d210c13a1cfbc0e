"""Which of the three output layouts a 2D detector's ONNX graph has, read from its inputs and outputs.

Why: detector exports differ in what is left inside the graph. YOLOX's export ends at the raw
prediction grid, NanoDet's at per-stride class and box-distribution maps, and torchvision- or
RT-DETR-style exports run the decoding and NMS inside and give boxes, scores and labels. The
runtime decodes each (a3d.runtime.detector2d.decoders) and feeds each its own input convention
(a3d.runtime.detector2d.preprocess), so the layout is decided once, when the file is opened.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import onnxruntime as ort

from a3d.runtime.errors import InputError

YOLOX, NANODET, BOXES = "yolox", "nanodet", "boxes"
YOLOX_STRIDES = (8, 16, 32)
NANODET_STRIDES = (8, 16, 32, 64)  # NanoDet-m has the first three, NanoDet-Plus all four
BOXES_WORDS = (("box",), ("score",), ("label", "class"))  # what the three outputs' names contain


@dataclass(frozen=True)
class Layout:
    """A detector graph as the runtime feeds and decodes it."""

    kind: str  # YOLOX, NANODET or BOXES
    input_name: str
    input_size: tuple[int, int] | None  # (height, width) the graph takes; None: any (boxes layout only)
    batched: bool  # the input is (1, 3, H, W), not (3, H, W)
    outputs: tuple[str, ...]  # in the decoder's order: yolox (grid,); nanodet class maps then
    # distribution maps, finest stride first; boxes (boxes, scores, labels)
    num_classes: int | None  # the class count the outputs fix (None: boxes layout)
    strides: tuple[int, ...] = ()


def find_layout(session: ort.InferenceSession, where: str) -> Layout:
    """The graph's layout; InputError "WHERE: ..." (one line) for a graph that has none of them."""
    inputs = session.get_inputs()
    if len(inputs) != 1 or len(inputs[0].shape) not in (3, 4) or inputs[0].type != "tensor(float)":
        shown = ", ".join(f"{i.name} {_shape(i.shape)} {i.type}" for i in inputs)
        expected = "one float image (1, 3, H, W) or (3, H, W)"
        raise InputError(f"{where}: a 2D detector takes {expected}; inputs: {shown}")
    image = inputs[0]
    height, width = image.shape[-2:]
    size = (height, width) if isinstance(height, int) and isinstance(width, int) else None
    outputs = {o.name: tuple(o.shape) for o in session.get_outputs()}
    batched = len(image.shape) == 4
    if size is not None:
        for found in (_yolox(outputs, size), _nanodet(outputs, size)):
            if found is not None:
                kind, names, classes, strides = found
                return Layout(kind, image.name, size, batched, names, classes, strides)
    names = _boxes(outputs)
    if names is not None:
        return Layout(BOXES, image.name, size, batched, names, None)
    shown = ", ".join(f"{name} {_shape(shape)}" for name, shape in outputs.items())
    raise InputError(
        f"{where}: unknown 2D detector layout: outputs {shown}; "
        "expected YOLOX's raw grid, NanoDet's, or boxes/scores/labels"
    )


def grid_cells(size: tuple[int, int], stride: int) -> int:
    """How many cells a stride's feature map has over an input of ``size`` (height, width)."""
    return math.ceil(size[0] / stride) * math.ceil(size[1] / stride)


_Found = tuple[str, tuple[str, ...], int, tuple[int, ...]]


def _yolox(outputs: dict[str, tuple], size: tuple[int, int]) -> _Found | None:
    """One (1, A, 5 + C) output whose A is the cell count of strides 8, 16 and 32."""
    if len(outputs) != 1:
        return None
    ((name, shape),) = outputs.items()
    if not _one_map(shape) or shape[2] <= 5:
        return None
    if shape[1] != sum(grid_cells(size, s) for s in YOLOX_STRIDES):
        return None
    return YOLOX, (name,), shape[2] - 5, YOLOX_STRIDES


def _nanodet(outputs: dict[str, tuple], size: tuple[int, int]) -> _Found | None:
    """Per stride a (1, HW, C) class map and a (1, HW, 4 * bins) distribution map, the class map
    listed first (as NanoDet's export lists them); the strides told by the cell counts."""
    if not outputs or len(outputs) % 2 or not all(_one_map(s) for s in outputs.values()):
        return None
    levels: dict[int, list[str]] = {}
    for name, shape in outputs.items():
        levels.setdefault(shape[1], []).append(name)
    strides = {grid_cells(size, s): s for s in NANODET_STRIDES}
    if any(len(pair) != 2 for pair in levels.values()) or not set(levels) <= set(strides):
        return None
    ordered = sorted(levels, reverse=True)  # finest stride (most cells) first
    class_maps = tuple(levels[n][0] for n in ordered)
    distribution_maps = tuple(levels[n][1] for n in ordered)
    classes = {outputs[n][2] for n in class_maps}
    widths = {outputs[n][2] for n in distribution_maps}
    if len(classes) != 1 or len(widths) != 1 or next(iter(widths)) % 4 or next(iter(widths)) < 8:
        return None
    return NANODET, class_maps + distribution_maps, classes.pop(), tuple(strides[n] for n in ordered)


def _boxes(outputs: dict[str, tuple]) -> tuple[str, ...] | None:
    """Three outputs named for boxes, scores and labels (or classes), in that order."""
    if len(outputs) != 3:
        return None
    picked = []
    for words in BOXES_WORDS:
        named = [n for n in outputs if any(w in n.lower() for w in words)]
        if len(named) != 1:
            return None
        picked.append(named[0])
    return tuple(picked) if len(set(picked)) == 3 else None


def _one_map(shape: tuple) -> bool:
    """A (1, N, K) output of fixed size."""
    return len(shape) == 3 and shape[0] == 1 and all(isinstance(d, int) for d in shape)


def _shape(shape: Sequence) -> str:
    return "(" + ", ".join(str(d) for d in shape) + ")"
