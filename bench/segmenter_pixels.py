"""A detector box's object pixels from a segmentation network, against the depth-layer rule.

    .venv/bin/python -m bench.segmenter_pixels FOLDER --segmenter deeplab.onnx [--rule layer|mask] \\
        -- bench.real_frames's arguments (--model real --out DIR)

The runtime finds a 2D detector box's object as the depth layer its inner half mostly lies in
(a3d.runtime.frontend.box_pixels). A semantic segmentation network trained on real photographs
(DeepLab v3 MobileNet V2, PASCAL VOC: chair, sofa, dining table, tv/monitor) marks the object's own
pixels where it knows the class; this measures whether they make better initial 3D centres, so
better 3D boxes, on the real frames (bench.real_frames's 2D and 3D numbers, run with the lifting
swapped):

- ``layer``: the layer is picked by the depth of the box's pixels that the segmenter marks as
  the box's class (instead of the inner half); the object is the box's pixels in that layer;
- ``mask``: the same layer, and only the marked pixels in it are the object.

A box with fewer than ``MIN_MARKED`` marked pixels with depth (or ``MIN_SHARE`` of the box), or of
a class VOC lacks, keeps the runtime's rule. The network ships as TFLite; converted once, at
development time (its sha256 and licence: the materials' README):

    pip install tf2onnx==1.17.0 tensorflow-cpu   # a separate environment
    python -m tf2onnx.convert --tflite deeplabv3_mnv2_pascal_quant.tflite --output deeplab.onnx --opset 17

(uint8 RGB 513 x 513 in, the label map out, the argmax inside the graph). The runtime has no
segmenter stage: docs/real-rooms.md gives what this measured.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from a3d.runtime import pipeline
from a3d.runtime.frontend.box_pixels import centres_of_masks, object_masks_in_boxes
from a3d.runtime.frontend.lifting import LiftedProposals
from a3d.runtime.pipeline import PipelineConfig, PreparedFrame
from a3d.runtime.structures.classes import CLASSES
from a3d.runtime.structures.frame import Frame
from a3d.runtime.structures.geometry import CameraLike
from bench import real_frames

VOC_LABELS = {"chair": 9, "table": 11, "sofa": 18, "monitor": 20, "television": 20}  # PASCAL VOC's indices
INPUT = 513
MIN_MARKED, MIN_SHARE = 50, 0.05


class Segmenter:
    """The VOC label map of a frame's colour image, computed once per frame when first asked."""

    def __init__(self, path: Path, threads: int = 2) -> None:
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        self._session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self._input = self._session.get_inputs()[0].name
        self.color: np.ndarray | None = None
        self._labels: np.ndarray | None = None

    def show(self, color: np.ndarray) -> None:
        self.color, self._labels = color, None

    def labels(self) -> np.ndarray:
        if self._labels is None:
            height, width = self.color.shape[:2]
            x = cv2.resize(self.color, (INPUT, INPUT), interpolation=cv2.INTER_LINEAR)[None].astype(np.uint8)
            out = np.asarray(self._session.run(None, {self._input: x})[0]).reshape(INPUT, INPUT)
            self._labels = cv2.resize(out.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST)
        return self._labels


def marked_pixels(labels: np.ndarray, boxes: np.ndarray, candidates: np.ndarray, depth: np.ndarray) -> list:
    """Per box, the (H, W) bool of its pixels the segmenter marks as one of its classes, or None
    where too few of them have depth (or VOC lacks its classes)."""
    out = []
    for (x1, y1, x2, y2), classes in zip(np.asarray(boxes).astype(int), candidates, strict=True):
        voc = [VOC_LABELS[CLASSES[c]] for c in np.flatnonzero(classes) if CLASSES[c] in VOC_LABELS]
        box = np.zeros(labels.shape, bool)
        box[max(y1, 0) : y2 + 1, max(x1, 0) : x2 + 1] = True
        marked = box & np.isin(labels, voc) & (depth > 0)
        enough = marked.sum() >= max(MIN_MARKED, MIN_SHARE * box.sum())
        out.append(marked if voc and enough else None)
    return out


def swap_lifting(segmenter: Segmenter, rule: str) -> None:
    """Make the pipeline lift detector boxes with the segmenter's pixels (module docstring)."""
    prepare, class_reach = pipeline.prepare, pipeline.class_reach
    seen: dict[str, np.ndarray] = {}

    def seeing_prepare(frame: Frame, config: PipelineConfig, timing: dict | None = None) -> PreparedFrame:
        segmenter.show(frame.color)
        return prepare(frame, config, timing)

    def noting_reach(candidates: np.ndarray, mean_sizes: np.ndarray) -> np.ndarray:
        seen["candidates"] = candidates
        return class_reach(candidates, mean_sizes)

    def lift(boxes: np.ndarray, reach: np.ndarray, raw: np.ndarray, filled: np.ndarray, K: CameraLike
             ) -> LiftedProposals:  # fmt: skip
        depth = np.where(raw > 0, raw, filled)
        voters = marked_pixels(segmenter.labels(), boxes, seen["candidates"], depth)
        masks = object_masks_in_boxes(boxes, reach, raw, filled, voters)
        if rule == "mask":
            masks = [
                ((x0, y0), m if v is None else m & v[y0 : y0 + m.shape[0], x0 : x0 + m.shape[1]])
                for ((x0, y0), m), v in zip(masks, voters, strict=True)
            ]
        return centres_of_masks(masks, raw, filled, K)

    pipeline.prepare, pipeline.class_reach, pipeline.lift_boxes = seeing_prepare, noting_reach, lift


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, theirs = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--segmenter", type=Path, required=True, help="the converted DeepLab ONNX file")
    p.add_argument("--rule", choices=("layer", "mask"), default="layer")
    args = p.parse_args(ours)
    swap_lifting(Segmenter(args.segmenter), args.rule)
    return real_frames.main([str(args.folder), *theirs])


if __name__ == "__main__":
    sys.exit(main())
