"""A model's card, read from its own metadata (``a3d-run --model-info NAME|FILE``).

Why: a model file travels alone (in the wheel, on a robot); what it is, what it was trained on and
under which licence its weights are must travel with it. a3d-export writes all of that into the
file's provenance (a3d.export.metadata); this prints it as a few lines a person reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from a3d.runtime.network.model import ModelMetadata


def _network(net: dict[str, Any]) -> str:
    color = net.get("color_width") or net.get("width")
    depth = net.get("width")
    trunks = (
        f"colour trunk VGG16 x {color:g}, depth trunk VGG16 x {depth:g}"
        if net.get("use_depth", True)
        else f"colour trunk VGG16 x {color:g} (no depth trunk)"
    )
    fused = f", fused to {net['fuse_channels']} channels" if net.get("fuse_channels") else ""
    return f"{trunks}{fused}, fc {net.get('fc6')}/{net.get('fc7')}"


def _finetune(card: dict[str, Any]) -> str:
    """a3d-finetune's line: from what, on what, and the held-back frames' mAP before and after."""
    data, scores = card.get("data", {}), card.get("heldout_map25", {})
    before, after = (scores.get(k) for k in ("before_present", "after_present"))
    change = f"{100 * before:.1f} -> {100 * after:.1f}" if before is not None and after is not None else "?"
    return (
        f"fine-tuned: from {card.get('base', {}).get('model', '?')} on {data.get('train_frames', '?')} "
        f"frames of {len(data.get('recordings', []))} recording(s) with synthetic ones; mAP@0.25 on their "
        f"{data.get('holdout_frames', '?')} held-back frames (their classes; the network alone) {change}"
    )


def model_card(path: str | Path, metadata: ModelMetadata) -> list[str]:
    """The card's lines: file, network, training, export, calibration, licence."""
    path = Path(path)
    prov = metadata.provenance
    config = prov.get("training_config") or {}
    solver = config.get("solver", {})
    data = prov.get("training_data") or {}
    export = prov.get("export") or {}
    checkpoint = prov.get("checkpoint") or {}
    lines = [f"model: {path} ({path.stat().st_size / 1e6:.1f} MB, schema {metadata.schema_version})"]
    if config.get("net"):
        lines.append(f"network: {_network(config['net'])}; input scale {metadata.input_scale:g}")
    init = "ImageNet VGG16 colour trunk" if solver.get("pretrained") else "random initialisation"
    if solver.get("init"):
        init = "fine-tuned from another model's weights"
    if solver.get("freeze_color"):
        init += f", {solver['freeze_color']} colour convolutions frozen"
    if data:
        batch = config.get("data", {}).get("images_per_batch", "?")
        lines.append(
            f"training: {data.get('frames', '?')} frames, {checkpoint.get('iteration', '?')} iterations of "
            f"{batch} images, {solver.get('precision', 'fp32')}; {init}"
        )
    if prov.get("finetune"):
        lines.append(_finetune(prov["finetune"]))
    quantised = "int8" if export.get("int8") else "float32"
    svd = f", fc SVD rank {export['svd_rank']}" if export.get("svd_rank") else ""
    made = f"a3d {prov.get('a3d_version', '?')}, {prov.get('exported_at', '?')}"
    lines.append(f"export: {quantised}{svd}, {made}")
    calibration = export.get("score_calibration") or {}
    if metadata.score_calibration is not None:
        share = calibration.get("right_share_at_0.5", {}).get("calibrated", {}).get("right_share")
        held = f"; {share:.0%} of its detections >= 0.5 right there" if share is not None else ""
        lines.append(f"scores: calibrated on {calibration.get('frames', '?')} frames{held}")
    else:
        lines.append("scores: the network's softmax, not calibrated")
    lines.append(f"weights licence: {prov.get('weights_licence', 'a3d (MIT); no third-party weights')}")
    return lines


DETECTOR_CARDS: dict[str, tuple[str, str]] = {
    "yolox-nano": (
        "YOLOX-Nano (Megvii; Ge et al., \"YOLOX: Exceeding YOLO Series in 2021\"), trained on COCO 2017 "
        "real photographs; its chair, couch, bed, dining table, toilet, tv and sink join a3d's classes",
        "Apache-2.0 (LICENSE-YOLOX.txt beside the model)",
    ),
}
"""What each bundled 2D detector is, was trained on, and its licence (a3d.runtime.detector2d.DETECTORS)."""


def detector_card(name: str) -> list[str]:
    """The lines a bundled pipeline adds to its network's card: its 2D detector."""
    what, licence = DETECTOR_CARDS[name]
    return [f"2D detector: {name}: {what}", f"2D detector licence: {licence}"]
