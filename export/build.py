"""a3d-export's work, from checkpoint to model file (torch and onnx: the 'train' extra).

1. load the checkpoint (a3d.train.checkpoint), optionally factorise fc6/fc7 (``--svd``, svd.py);
2. export the runtime graph with the target statistics folded in (onnx_export.py), onnx.checker;
3. verify the float32 file as the runtime opens it against eager torch on the first frames of
   ``--verify-frames`` (or a synthetic image): above the tolerances of verify.py it stops with
   exit code 1 and writes nothing; with ``--svd`` the difference to the uncompressed network is
   reported too;
4. ``--int8``: static QDQ quantisation calibrated on ``--calib`` frames (quantize.py), checked
   to load and give finite outputs, its difference to torch reported;
5. ``--score-calibration``: run the final model through the runtime on FOLDER's annotated frames
   and fit its per-class score calibration (score_calibration.py) into the metadata;
6. write the model with its metadata (metadata.py; the verification numbers go into the
   provenance) atomically to ``-o`` and load it back.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path

import onnx

from a3d.export.base import MAX_IR_VERSION, PROG, VERIFY_FRAMES, ExportError
from a3d.export.metadata import build_metadata
from a3d.export.onnx_export import RuntimeGraph, export_graph, save_model
from a3d.export.quantize import CALIB_ROIS, quantize_int8
from a3d.export.roi_pool_onnx import network_pool_chunks
from a3d.export.score_calibration import REPORT_THRESHOLD, calibrate
from a3d.export.svd import svd_compress
from a3d.export.verify import (
    DELTA_RTOL,
    PROB_ATOL,
    NetworkInputs,
    VerificationError,
    check_graph,
    compare,
    folder_inputs,
    synthetic_inputs,
)
from a3d.runtime.network.model import DetectorModel, ModelMetadata
from a3d.runtime.pipeline import PipelineConfig
from a3d.train.checkpoint import load_trained
from a3d.train.inference import TorchNetwork


def export(args: argparse.Namespace) -> Path:
    """Steps 1-6 of the module docstring; returns the path written (VerificationError: step 3)."""
    trained = load_trained(args.checkpoint)
    if trained.config.net.roi_pool != "align":
        raise ExportError(
            f"{args.checkpoint}: network uses {trained.config.net.roi_pool!r} RoI pooling, a training-only "
            "ablation; a3d-export exports RoIAlign networks (net.roi_pool=align)"
        )
    reference = trained.net
    options: dict = {"opset": args.opset, "int8": args.int8, "svd_rank": args.svd}
    if args.svd is not None:
        reference, options["svd"] = svd_compress(trained.net, args.svd)
        for name, info in options["svd"].items():
            kept = 100 * info["energy_kept"]
            _log(f"svd {name} {info['shape']} rank {info['rank']}: {info['parameters']} -> "
                 f"{info['parameters_svd']} weights, {kept:.2f}% of the energy kept")  # fmt: skip
    metadata = build_metadata(trained.state, trained.config, args.checkpoint, min_score=args.score_threshold,
                              pool_chunks=network_pool_chunks(trained.net))  # fmt: skip
    pipeline = PipelineConfig.from_metadata(metadata)  # the front end a3d-run will use with this model
    regress_3d = trained.config.inference.regress_3d
    torch_net = TorchNetwork(reference, trained.stats, regress_3d)
    if args.verify_frames is not None:
        inputs = list(folder_inputs(args.verify_frames, pipeline, VERIFY_FRAMES))
    else:
        inputs = [synthetic_inputs(metadata.input_scale)]
    report: dict = {"inputs": [i.name for i in inputs], "prob_atol": PROB_ATOL, "delta_rtol": DELTA_RTOL}
    with tempfile.TemporaryDirectory(prefix="a3d-export-") as tmp:
        work = Path(tmp)
        model = export_graph(
            RuntimeGraph(reference, trained.stats, regress_3d), work / "graph.onnx", args.opset
        )
        check_graph(work / "graph.onnx")
        opened = _open(model, metadata, work / "float.onnx", args.threads)
        parity = compare(opened, torch_net, inputs)
        _log(f"float32 ONNX Runtime vs torch: {parity.describe()}")
        if not parity.within():
            limits = f"probs {PROB_ATOL:g} abs, deltas {DELTA_RTOL:g} rel"
            raise VerificationError(f"{parity.describe()} exceeds {limits}; nothing written")
        report["float32_vs_torch"] = parity.to_dict()
        if args.svd is not None:
            lossy = compare(opened, TorchNetwork(trained.net, trained.stats, regress_3d), inputs)
            _log(f"svd rank {args.svd} vs the uncompressed network: {lossy.describe()}")
            report["float32_vs_uncompressed"] = lossy.to_dict()
        if args.int8:
            calibration = folder_inputs(args.calib, pipeline, args.calib_frames)
            model, options["calibration"], report["int8_vs_torch"] = _int8(
                args, calibration, torch_net, metadata, inputs, work
            )
        if args.score_calibration is not None:
            final = _open(model, metadata, work / "final.onnx", args.threads)
            calibration, options["score_calibration"] = calibrate(final, args.score_calibration, PROG)
            metadata = dataclasses.replace(metadata, score_calibration=calibration)
            _log(f"score calibration: {_describe_calibration(options['score_calibration'])}")
    provenance = {**metadata.provenance, "export": {**metadata.provenance["export"], **options}}
    metadata = dataclasses.replace(metadata, provenance={**provenance, "verification": report})
    save_model(model, metadata, args.output)
    DetectorModel.load(args.output, args.threads)  # the bytes on disk open as the runtime opens them
    return args.output


def _int8(
    args: argparse.Namespace,
    calibration: Iterable[NetworkInputs],
    reference: TorchNetwork,
    metadata: ModelMetadata,
    inputs: list[NetworkInputs],
    work: Path,
) -> tuple[onnx.ModelProto, dict, dict]:
    """Quantise work/graph.onnx; the int8 model, the calibration summary and its comparison to torch."""
    frames = quantize_int8(work / "graph.onnx", work / "int8.onnx", calibration)
    check_graph(work / "int8.onnx")
    model = onnx.load(str(work / "int8.onnx"))
    model.ir_version = min(model.ir_version, MAX_IR_VERSION)
    quantized = compare(_open(model, metadata, work / "int8.a3d.onnx", args.threads), reference, inputs)
    _log(f"int8 ({frames} calibration frames) vs torch: {quantized.describe()}")
    if not quantized.finite():
        raise VerificationError(f"the int8 model gives non-finite outputs ({quantized.describe()})")
    calibration_info = {"folder": str(args.calib.resolve()), "frames": frames, "rois_per_frame": CALIB_ROIS}
    return model, calibration_info, quantized.to_dict()


def _describe_calibration(report: dict) -> str:
    shares = report[f"right_share_at_{REPORT_THRESHOLD}"]
    parts = [
        f"{s['detections']} score >= {REPORT_THRESHOLD} with the {name} scores, "
        + ("none" if s["right_share"] is None else f"{100 * s['right_share']:.0f}% of them right")
        for name, s in shares.items()
    ]
    return (f"{report['detections']} detections on {report['frames']} frames, {report['right']} right "
            f"(3D IoU >= {report['iou']}); " + "; ".join(parts))  # fmt: skip


def _open(model: onnx.ModelProto, metadata: ModelMetadata, path: Path, threads: int) -> DetectorModel:
    """Write ``model`` with ``metadata`` to ``path`` and open it as the runtime does."""
    save_model(model, metadata, path)
    return DetectorModel.load(path, threads)


def _log(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)
