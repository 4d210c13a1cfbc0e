"""Where the network's time goes: ONNX Runtime's own profile, per operator, split into trunks and head.

Two sessions of the model file, one after the other, with the runtime's settings (threads,
one inter-op thread, full graph optimisation), so the nodes are the ones a3d-run executes:

1. shapes: weight prepacking off (a prepacked weight drops out of the profile's input shapes),
   one call with all RoIs and one with half of them. A node whose shapes change with the RoI
   count works per RoI: the **head** (RoI pooling, fc6 / fc7, the outputs); the rest runs once
   per frame: the **trunks** (both VGG trunks and the 1 x 1 channel fusion on their maps). Each
   convolution and matrix product's multiply-adds (MACs) come from its shapes.
2. times: the normal session (prepacked weights), a warm-up call, then ``calls`` profiled calls
   with all RoIs; each node's median kernel time (robust to a preempted call on a shared machine).

Each node is judged against the ceiling of its kind and precision (bench.ceilings): a
convolution against the convolution ceiling, a matrix product against the GEMM ceiling, int8
kernels (QLinearConv, QGemm, ...) against int8, the others against fp32. In the int8 export the
RoI pooling's row products are integer, its column products fp32 (export/quantize.py).
"""

from __future__ import annotations

import json
import math
import tempfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import onnxruntime as ort

from a3d.runtime.network.model import session_options
from a3d.runtime.network.roi_order import pooling_order
from bench.ceilings import Ceilings

# op name -> index of the weight input (convolutions) or of the B input (matrix products)
CONV_WEIGHT = {
    "Conv": 1,
    "FusedConv": 1,
    "NhwcConv": 1,
    "NhwcFusedConv": 1,
    "ConvInteger": 1,
    "QLinearConv": 3,
}
GEMM_B = {"MatMul": 1, "FusedMatMul": 1, "Gemm": 1, "FusedGemm": 1, "MatMulInteger": 1,
          "MatMulIntegerToFloat": 1, "DynamicQuantizeMatMul": 1, "QLinearMatMul": 3, "QGemm": 3}  # fmt: skip
INT8_OPS = {"ConvInteger", "QLinearConv", "MatMulInteger", "MatMulIntegerToFloat", "DynamicQuantizeMatMul",
            "QLinearMatMul", "QGemm"}  # fmt: skip
PARTS = ("trunks", "head")
FULLY_CONNECTED = {"Gemm", "FusedGemm", "QGemm", "Softmax", "Relu"}  # the head's layers after pooling


@dataclass
class OpStat:
    """One operator type in one part: mean seconds per call (all its nodes), MACs, node count."""

    part: str
    op: str
    seconds: float = 0.0
    macs: int = 0
    nodes: int = 0

    @property
    def kind(self) -> str:
        return "conv" if self.op in CONV_WEIGHT else "gemm" if self.op in GEMM_B else ""

    @property
    def int8(self) -> bool:
        return self.op in INT8_OPS

    def ceiling(self, ceilings: Ceilings) -> float:
        """MAC/s this op type could reach here (0 for ops without MACs)."""
        if self.kind == "conv":
            return ceilings.conv(self.int8)
        return ceilings.gemm(self.int8) if self.kind == "gemm" else 0.0


@dataclass
class NetworkProfile:
    """Per (part, op type) time and work of one model on one frame's inputs (``rois`` RoIs)."""

    model: str
    rois: int
    calls: int
    ops: list[OpStat] = field(default_factory=list)

    def seconds(self, part: str) -> float:
        return sum(o.seconds for o in self.ops if o.part == part)

    def macs(self, part: str) -> int:
        return sum(o.macs for o in self.ops if o.part == part)

    def pooling_seconds(self) -> float:
        """The RoI pooling: the head less its fully connected layers (FULLY_CONNECTED), i.e. the
        pooling's products, the RoIs' weights and the reshaping between them."""
        return sum(o.seconds for o in self.ops if o.part == "head" and o.op not in FULLY_CONNECTED)

    def seconds_at_ceiling(self, part: str, ceilings: Ceilings) -> float:
        """The part's MACs at the ceiling of each op's kind and precision (0 s for the other ops)."""
        return sum(o.macs / o.ceiling(ceilings) for o in self.ops if o.part == part and o.macs)

    def int8(self) -> bool:
        return any(o.int8 for o in self.ops)

    @classmethod
    def from_dict(cls, data: dict) -> NetworkProfile:
        ops = [OpStat(**o) for o in data.pop("ops")]
        return cls(**{k: v for k, v in data.items() if k != "peak_bytes"}, ops=ops)


def node_macs(op: str, inputs: list[list[int]], output: list[int]) -> int:
    """Multiply-adds of one convolution or matrix product from its profiled shapes (0 otherwise).

    Convolution: output elements x weight elements per output channel (C_in / groups x kh x kw).
    Matrix product: output elements x K, K from A when A has the output's rank (one matrix of A's
    elements per output row, right whether A is transposed or not, and whether A's batch is
    broadcast or not), else from a 2-D or batched B.
    """
    if op in CONV_WEIGHT:
        weight = inputs[CONV_WEIGHT[op]]
        return math.prod(output) * math.prod(weight[1:])
    if op in GEMM_B:
        a, b = inputs[0], inputs[GEMM_B[op]]
        if len(a) == len(output):
            k = math.prod(a[-2:]) // output[-2]
        else:
            k = math.prod(b) // (output[-1] * math.prod(b[:-2]))
        return math.prod(output) * k
    return 0


def profile_network(
    model: Path, feeds: dict[str, np.ndarray], threads: int, calls: int = 5
) -> NetworkProfile:
    """Profile ``model`` on one frame's ``feeds`` (color, depth, rois, context_rois); module docstring."""
    rois = len(feeds["rois"])
    if rois < 2:
        raise ValueError(
            "profiling needs a frame with at least 2 RoIs (head = the nodes that change with them)"
        )
    order = pooling_order(feeds["rois"], feeds["context_rois"])  # as DetectorModel.run hands them over
    feeds = {k: v[order] if k.endswith("rois") else v for k, v in feeds.items()}
    half = {k: v[: rois // 2] if k.endswith("rois") else v for k, v in feeds.items()}
    with tempfile.TemporaryDirectory(prefix="a3d-profile-") as tmp:
        full_shapes, half_shapes = _node_runs(
            model, [feeds, half], threads, Path(tmp) / "shapes", prepack=False
        )
        timed = _node_runs(model, [feeds] * (calls + 1), threads, Path(tmp) / "times", prepack=True)[1:]
    stats: dict[tuple[str, str], OpStat] = {}
    for name, (op, inputs, output, _) in full_shapes.items():
        part = "head" if half_shapes.get(name, (None,) * 4)[1:3] != (inputs, output) else "trunks"
        stat = stats.setdefault((part, op), OpStat(part, op))
        stat.macs += node_macs(op, inputs, output)
        stat.nodes += 1
        stat.seconds += float(np.median([run[name][3] for run in timed if name in run] or [0.0]))
    return NetworkProfile(model.name, rois, calls, sorted(stats.values(), key=lambda s: -s.seconds))


def _node_runs(model: Path, feeds: list[dict[str, np.ndarray]], threads: int, prefix: Path,
               prepack: bool) -> list[dict[str, tuple]]:  # fmt: skip
    """One profiled session, one call per item of ``feeds``: per call, node name -> (op, input
    shapes, first output's shape, kernel seconds)."""
    options = session_options(threads)  # as a3d-run opens the model
    options.enable_profiling = True
    options.profile_file_prefix = str(prefix)
    if not prepack:
        options.add_session_config_entry("session.disable_prepacking", "1")
    session = ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
    for item in feeds:
        session.run(None, item)
    events = json.loads(Path(session.end_profiling()).read_text())
    runs = sorted((e["ts"], e["ts"] + e["dur"]) for e in events if e.get("name") == "model_run")
    nodes: list[dict[str, tuple]] = [defaultdict(tuple) for _ in runs]
    for e in events:
        if e.get("cat") != "Node" or not e["name"].endswith("_kernel_time"):
            continue
        at = next(i for i, (start, end) in enumerate(runs) if start <= e["ts"] <= end)
        args = e["args"]
        shapes = [next(iter(s.values())) for s in args.get("input_type_shape", [])]
        output = next(iter(args["output_type_shape"][0].values())) if args.get("output_type_shape") else []
        nodes[at][e["name"].removesuffix("_kernel_time")] = (args["op_name"], shapes, output, e["dur"] * 1e-6)
    return [dict(n) for n in nodes]
