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
    if solver.get("freeze_color"):
        init += f", {solver['freeze_color']} colour convolutions frozen"
    if data:
        batch = config.get("data", {}).get("images_per_batch", "?")
        lines.append(
            f"training: {data.get('frames', '?')} frames, {checkpoint.get('iteration', '?')} iterations of "
            f"{batch} images, {solver.get('precision', 'fp32')}; {init}"
        )
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
