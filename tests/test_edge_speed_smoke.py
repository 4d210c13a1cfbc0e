"""Smoke test of bench.edge_speed on a tiny model: its functions build, export and time a run.

No timing is asserted (the machine is shared); what is checked is the bookkeeping: every stage
of a3d-run is accounted for, the stages of a sequential run add up to its frame time, and the
network-alone measurement sees the very inputs a3d-run fed the model.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bench import edge_report, edge_speed
from tests.helpers.synth_frames import write_synth_frames

# slow: an ONNX export and timed a3d-run processes
pytestmark = [
    pytest.mark.slow,
    pytest.mark.filterwarnings("ignore::FutureWarning", "ignore::DeprecationWarning"),
]
TINY = {
    # width 0.25: every convolution has a multiple of 16 channels, so ONNX Runtime's blocked (NCHWc)
    # layout pads none of them on AVX-512 (blocks of 16) or AVX2 (8) and the MACs count by hand
    "net": {"width": 0.25, "fuse_channels": 16, "fc6": 32, "fc7": 32},
    "data": {"input_scale": 0.5},
    "proposals": {"min_area": 20, "max_proposals": 60},
}


@dataclass(frozen=True)
class Tiny:
    checkpoint: Path
    model: Path
    frames: Path  # the first 3 of 4 test frames


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Tiny:
    root = tmp_path_factory.mktemp("edge")
    frames = write_synth_frames(root / "synth", 4)
    checkpoint = edge_speed.random_checkpoint(root / "run" / "checkpoint.pt", "cpu-eighth", TINY)
    model = root / "tiny.onnx"
    edge_speed.export_model(checkpoint, model, frames, threads=1)
    subset = edge_speed.frame_subset(frames, root / "subset", 3)
    names = sorted(p.name for p in subset.glob("*.color.png"))
    assert names == [f"synth_00000{i}.color.png" for i in range(3)]
    return Tiny(checkpoint, model, subset)


def test_breakdown_accounts_for_the_whole_frame(tiny: Tiny, tmp_path: Path) -> None:
    rrd = tmp_path / "run.rrd"
    run = edge_speed.measure_run(tiny.model, tiny.frames, max_proposals=40, threads=1, rrd=rrd)
    assert run.frames == 3 and 0 < run.rois <= 40 and rrd.stat().st_size > 0
    assert set(run.stages) == set(edge_report.RUN_STAGES) == set(edge_report.STAGE_LABELS)  # each a row
    assert all(seconds >= 0 for seconds in run.stages.values())
    assert run.stages["network"] > 0 and run.stages["output"] > 0 and run.stages["rerun"] > 0
    # Sequential: the frame period is the stages plus a little loop overhead (progress bar, generator).
    assert run.stage_sum <= run.frame_seconds * 1.05 + 2e-3
    assert run.frame_seconds <= run.stage_sum * 1.25 + 0.02

    alone = edge_speed.measure_ort(tiny.model, tiny.frames, max_proposals=40, threads=1)
    assert alone.rois == pytest.approx(run.rois)  # the network alone sees a3d-run's inputs
    assert alone.seconds > 0 and alone.one_roi_seconds > 0


def test_a_slow_warm_up_frame_stays_out_of_the_period(tiny: Tiny, monkeypatch: pytest.MonkeyPatch) -> None:
    """The warm-up frame is left out of the stage means, so it must be left out of the period too:
    a stall while a3d-run writes the first line (a cold fsync on a busy disk, the first rerun log)
    once made the period 3 x the stages."""
    fsync, calls = os.fsync, []

    def first_fsync_stalls(fd: int) -> None:
        calls.append(fd)
        if len(calls) == 1:
            time.sleep(0.5)
        fsync(fd)

    monkeypatch.setattr(os, "fsync", first_fsync_stalls)
    run = edge_speed.measure_run(tiny.model, tiny.frames, max_proposals=40, threads=1)
    assert len(calls) >= 2  # the first line, then at most once a second, and the end
    assert run.frame_seconds <= run.stage_sum * 1.25 + 0.02


VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)


def vgg16_trunk_macs(height: int, width: int, scale: float) -> tuple[int, int, int, int]:
    """(MACs of one VGG16 trunk of ``scale`` x the channels, channels, height, width of conv5_3)."""
    macs, channels = 0, 3
    for layer in VGG16:
        if layer == "M":
            height, width = -(-height // 2), -(-width // 2)  # ceil_mode, as Caffe
            continue
        out = round(layer * scale)
        macs += height * width * channels * out * 9
        channels = out
    return macs, channels, height, width


def test_profile_finds_the_parts_and_their_macs(tiny: Tiny) -> None:
    """The profile's MACs equal the network's by hand: two VGG16 trunks at the input size plus the
    two 1 x 1 channel fusions, RoI and context (trunks); fc6 / fc7 / the three outputs per RoI (the
    head's weighted GEMMs)."""
    profile = edge_speed.measure_profile(tiny.model, tiny.frames, max_proposals=40, threads=1)
    item = max(edge_speed.network_inputs(tiny.model, tiny.frames, 40, count=2), key=lambda i: len(i.rois))
    assert profile.rois == len(item.rois) >= 2
    net = TINY["net"]
    trunk, channels, h, w = vgg16_trunk_macs(*item.color_input.shape[2:], net["width"])
    fusion = 2 * h * w * 2 * channels * net["fuse_channels"]
    assert profile.macs("trunks") == 2 * trunk + fusion
    fc6_in = 2 * net["fuse_channels"] * 7 * 7  # the RoI's and its context's pooled maps
    per_roi = fc6_in * net["fc6"] + net["fc6"] * net["fc7"] + net["fc7"] * 20 * (1 + 7 + 4)
    weighted = sum(o.macs for o in profile.ops if o.part == "head" and o.op in ("Gemm", "FusedGemm"))
    assert weighted == profile.rois * per_roi
    pooling = sum(o.macs for o in profile.ops if o.part == "head" and o.op in ("MatMul", "FusedMatMul"))
    assert profile.macs("head") == weighted + pooling > weighted  # RoI pooling: products of computed tensors
    assert profile.seconds("trunks") > 0 and profile.seconds("head") > 0
    assert not profile.int8()


def test_ceiling_graphs_compute_what_their_macs_count() -> None:
    """The ceilings divide MACs by time: the graphs must be the products they claim to be."""
    import onnxruntime as ort

    from bench.ceilings import conv_graph, gemm_graph, measure_ceilings

    def run(model, feeds):
        session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
        return session.run(None, feeds)[0]

    model, feeds = gemm_graph(8, 16, 24, int8=False)
    weight = onnx_numpy(model, "w")
    np.testing.assert_allclose(run(model, feeds), feeds["x"] @ weight, rtol=1e-5, atol=1e-4)
    model, feeds = gemm_graph(8, 16, 24, int8=True)
    # Activations <= 128: AVX2 without VNNI adds uint8 x int8 products in pairs into int16, which
    # saturates above 2 x 128 x 127 (the int8 model's own accuracy on such a machine is another matter).
    feeds["x"] = np.random.default_rng(1).integers(0, 129, feeds["x"].shape, dtype=np.uint8)
    exact = (feeds["x"].astype(np.int64) - 128) @ onnx_numpy(model, "w").astype(np.int64)
    expected = np.clip(np.round(exact * 0.02 * 0.01 / 0.5) + 128, 0, 255)
    assert np.abs(run(model, feeds).astype(np.int64) - expected).max() <= 1
    model, feeds = conv_graph(4, 6, 5, 7, int8=False)
    out = run(model, feeds)
    padded = np.pad(feeds["x"][0], ((0, 0), (1, 1), (1, 1)))
    weight, bias = onnx_numpy(model, "w"), onnx_numpy(model, "b")
    by_hand = np.einsum(
        "oikl,iyxkl->oyx", weight, np.lib.stride_tricks.sliding_window_view(padded, (3, 3), (1, 2))
    )
    np.testing.assert_allclose(out[0], by_hand + bias[:, None, None], rtol=1e-4, atol=1e-4)

    ceilings = measure_ceilings(threads=1, scale=1 / 16, repeats=1)
    rates = [ceilings.gemm_fp32, ceilings.gemm_int8, ceilings.conv_fp32, ceilings.conv_int8]
    assert all(np.isfinite(r) and r > 1e6 for r in rates)


def onnx_numpy(model, name: str) -> np.ndarray:
    from onnx import numpy_helper

    return next(numpy_helper.to_array(t) for t in model.graph.initializer if t.name == name)


def test_a_child_reports_its_own_peak_memory_not_its_parents() -> None:
    ballast = np.ones(64 * 2**20)  # 512 MiB resident in this process
    code = "from bench.edge_speed import peak_resident_bytes; print(peak_resident_bytes())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=edge_speed.REPO)  # fmt: skip
    assert int(out.stdout) < 256 * 2**20 < ballast.nbytes


def test_targets_judge_what_was_measured(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The report's verdicts from made-up measurements: trunks at 60 % of a ceiling that the second
    ceiling run raised, auto overlap slower than sequential for one model only, no VNNI."""
    from bench.ceilings import Ceilings
    from bench.edge_report import NetworkResult, RunResult
    from bench.network_profile import NetworkProfile, OpStat

    monkeypatch.setattr(edge_report, "cpu_flags", lambda: frozenset({"avx2"}))
    start = Ceilings(gemm_fp32=20e9, gemm_int8=30e9, conv_fp32=20e9, conv_int8=25e9, threads=2)
    end = Ceilings(gemm_fp32=25e9, gemm_int8=40e9, conv_fp32=15e9, conv_int8=50e9, threads=2)
    ops = [OpStat("trunks", "QLinearConv", seconds=1.0, macs=30_000_000_000, nodes=26),  # at 50 G: 0.6 s
           OpStat("head", "QGemm", seconds=0.2, macs=4_000_000_000, nodes=7),  # at 40 G: 0.1 s
           OpStat("head", "Transpose", seconds=0.1, nodes=2)]  # fmt: skip
    slow = [*ops[:2], OpStat("head", "Transpose", seconds=0.3, nodes=2)]  # a round in a slow spell
    stages = {s: 0.01 for s in edge_report.RUN_STAGES} | {"network": 1.3}

    def run(model: str, overlap: str, seconds: float) -> RunResult:
        return RunResult(model, overlap, 8, 100.0, stages, seconds, overlapped=6 * (overlap != "off"),
                         peak_bytes=2**30)  # fmt: skip

    m = edge_report.Measurements(
        ceiling_runs=[start, end],
        full=[run("a", "off", 1.5), run("a", "on", 1.9), run("a", "auto", 1.52)],
        small=[run("b", "off", 0.5), run("b", "on", 0.4), run("b", "auto", 0.6)],
        networks={
            key: NetworkResult("onnxruntime", key, seconds, 1.0, 100.0)
            for key, seconds in (("ort int8 + SVD", 1.3), ("ort fp32", 2.0), ("ort small model", 0.2))
        },
        profiles={"int8 + SVD": NetworkProfile("a.onnx", 100, 5, ops)},
        int8_profiles=[NetworkProfile("a.onnx", 100, 5, slow), NetworkProfile("a.onnx", 100, 5, ops)],
    )
    assert m.ceilings.conv_int8 == 50e9 and m.ceilings.conv_fp32 == 20e9  # each ceiling's best run
    edge_report.print_targets(m)
    edge_report.print_parts("a", m.profiles["int8 + SVD"], m.ceilings, m.full[0])
    out = capsys.readouterr().out
    assert "[FAIL] int8 trunks >= 75% of the measured int8 convolution ceiling: 60%" in out
    assert (
        "[PASS] int8 + SVD end to end <= 1.25 x its network alone: 1.500 s vs 1.25 x 1.300 s (sequential)"
        in out
    )
    assert "[n/a ] int8 + SVD end to end <= 0.739 s" in out and "0.900 s projected" in out  # 0.6 + 0.1 + 0.2
    assert "[PASS] --overlap auto never slower than sequential, full model" in out  # 1.52 <= 1.05 x 1.5
    assert "[FAIL] --overlap auto never slower than sequential, small model" in out  # 0.6 > 1.05 x 0.5
    assert "[PASS] peak resident memory" in out
    pooling = "[FAIL] RoI pooling <= 25 ms at 100 RoIs (int8 + SVD head less its fully connected layers)"
    # the Transpose; the QGemm is a fully connected layer; every round's pooling is shown
    assert f"{pooling}: 100.0 ms (the fastest profile's; each round's: 300.0, 100.0 ms)" in out
    trunks = next(line for line in out.splitlines() if line.strip().startswith("trunks"))
    assert trunks.split()[1:] == ["30.0", "1000.0", "600.0", "60%"]


def test_matrix_product_macs_count_a_broadcast_batch() -> None:
    """The pooling's column products, (K, 1, 7, w) x (K, 7, w, C): every one of the K x 7 batches
    multiplies 7 x w by w x C, although A holds only K of them."""
    from bench.network_profile import node_macs

    assert node_macs("MatMul", [[16, 1, 7, 12], [16, 7, 12, 512]], [16, 7, 7, 512]) == 16 * 7 * 7 * 12 * 512
    assert node_macs("MatMul", [[112, 9], [9, 6144]], [112, 6144]) == 112 * 9 * 6144
    assert node_macs("FusedMatMul", [[9, 112], [9, 6144]], [112, 6144]) == 112 * 9 * 6144  # A transposed
