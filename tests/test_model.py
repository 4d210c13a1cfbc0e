"""A3DNet and its configuration: VGG16 layout, layouts of the pooled features, ablations."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch

from a3d.runtime.io.plain_config import apply_plain, plain_from_dataclass
from a3d.runtime.structures.classes import NUM_OUTPUTS
from a3d.train.model.config import PRESETS, NetConfig, preset
from a3d.train.model.net import A3DNet
from a3d.train.model.roi_pool import roi_align, roi_max_pool
from a3d.train.model.vgg import VGG16Trunk, conv5_size

TINY = NetConfig(width=0.125, fc6=32, fc7=32, dropout=0.0)
TORCHVISION_VGG16_CONVS = {  # features index: (out, in) of torchvision.models.vgg16()
    0: (64, 3), 2: (64, 64), 5: (128, 64), 7: (128, 128), 10: (256, 128), 12: (256, 256),
    14: (256, 256), 17: (512, 256), 19: (512, 512), 21: (512, 512), 24: (512, 512),
    26: (512, 512), 28: (512, 512),
}  # fmt: skip


def _inputs(batch: int = 2, height: int = 64, width: int = 80, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    color = torch.randn(batch, 3, height, width, generator=gen)
    depth = torch.randn(batch, 3, height, width, generator=gen)
    rois = torch.tensor([[0, 4.0, 6.0, 40.0, 50.0], [1, -10.0, 3.0, 70.0, 60.0], [1, 30.0, 20.0, 35.0, 29.0]])
    context = torch.tensor(
        [[0, -5.0, -5.0, 60.0, 63.0], [1, -30.0, -10.0, 79.5, 63.5], [1, 20.0, 10.0, 50.0, 40.0]]
    )
    return color, depth, rois, context


def _record_fc6_input(net: A3DNet) -> dict[str, torch.Tensor]:
    seen: dict[str, torch.Tensor] = {}

    def hook(_module: torch.nn.Module, args: tuple[torch.Tensor, ...]) -> None:
        seen["x"] = args[0]

    net.fc6.register_forward_pre_hook(hook)
    return seen


def test_width_one_trunk_is_vgg16_exactly() -> None:
    with torch.device("meta"):
        trunk = VGG16Trunk(1.0)
        conv5 = trunk(torch.empty(1, 3, 427, 561))
    shapes = {i: tuple(conv.weight.shape) for i, conv in trunk.convs()}
    assert shapes == {i: (o, c, 3, 3) for i, (o, c) in TORCHVISION_VGG16_CONVS.items()}
    assert sum(p.numel() for p in trunk.parameters()) == 14_714_688  # torchvision vgg16().features
    assert tuple(conv5.shape) == (1, 512, 27, 36) == (1, 512, *conv5_size(427, 561))


@pytest.mark.parametrize("width", [0.5, 0.25, 0.125])
def test_width_scaled_trunks_keep_the_layout(width: float) -> None:
    with torch.device("meta"):
        trunk = VGG16Trunk(width)
    shapes = {i: tuple(conv.weight.shape[:2]) for i, conv in trunk.convs()}
    assert shapes == {i: (round(o * width), 3 if i == 0 else round(c * width))
                      for i, (o, c) in TORCHVISION_VGG16_CONVS.items()}  # fmt: skip
    assert trunk.out_channels == round(512 * width)


@pytest.mark.parametrize(
    ("config", "fc6_inputs"),
    [
        (TINY, 4 * 64 * 49),  # paper: 4 blocks [colour, depth] x [RoI, context]
        (NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16), 2 * 16 * 49),
        (NetConfig(width=0.125, fc6=32, fc7=32, use_depth=False), 2 * 64 * 49),
        (NetConfig(width=0.125, fc6=32, fc7=32, use_context=False), 2 * 64 * 49),
        (NetConfig(width=0.125, fc6=32, fc7=32, use_depth=False, use_context=False, fuse_channels=8), 8 * 49),
        (NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16, roi_pool="max"), 2 * 16 * 49),
    ],
)
def test_output_shapes_and_fc6_size(config: NetConfig, fc6_inputs: int) -> None:
    net = A3DNet(config).eval()
    color, depth, rois, context = _inputs()
    with torch.no_grad():
        logits, deltas3d, deltas2d = net(color, depth, rois, context)
    assert net.fc6.in_features == fc6_inputs
    assert logits.shape == (3, NUM_OUTPUTS)
    assert deltas3d.shape == (3, NUM_OUTPUTS * 7)
    assert deltas2d.shape == (3, NUM_OUTPUTS * 4)
    features = net.trunk_features(color, depth)
    assert features.shape == (2, 64 * (2 if config.use_depth else 1), 4, 5)
    with torch.no_grad():
        split = net.head(features, rois, context)
    assert all(torch.equal(a, b) for a, b in zip(split, (logits, deltas3d, deltas2d), strict=True))


@pytest.mark.parametrize(("kind", "pool"), [("align", roi_align), ("max", roi_max_pool)])
def test_plain_layout_feeds_fc6_the_pooled_blocks_in_order(kind: str, pool) -> None:
    """fc6's input is [colour RoI, depth RoI, colour context, depth context], each (C, y, x)."""
    net = A3DNet(replace(TINY, roi_pool=kind)).eval()
    color, depth, rois, context = _inputs()
    seen = _record_fc6_input(net)
    with torch.no_grad():
        net(color, depth, rois, context)
        blocks = [pool(trunk(image), boxes) for boxes in (rois, context)
                  for trunk, image in ((net.color_trunk, color), (net.depth_trunk, depth))]  # fmt: skip
    torch.testing.assert_close(seen["x"], torch.cat([b.flatten(1) for b in blocks], dim=1))


@pytest.mark.parametrize("fused", [48, 80])
def test_fused_layout_starts_as_the_trunk_average(fused: int) -> None:
    """fuse convs start as the mean of both trunks' leading channels (64 here), zeros beyond."""
    net = A3DNet(NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=fused)).eval()
    color, depth, rois, context = _inputs()
    seen = _record_fc6_input(net)
    with torch.no_grad():
        net(color, depth, rois, context)
        mean = (net.color_trunk(color) + net.depth_trunk(depth)) / 2
        padded = torch.zeros(2, fused, *mean.shape[2:])
        padded[:, : min(fused, 64)] = mean[:, :fused]
        want = torch.cat([roi_align(padded, boxes).flatten(1) for boxes in (rois, context)], 1)
    torch.testing.assert_close(seen["x"], want)


def test_ablations_ignore_their_inputs() -> None:
    color, depth, rois, context = _inputs()
    other_depth, other_context = depth.flip(2), context[[2, 0, 1]]
    for config, changed, same in [
        (replace(TINY, use_depth=False), (color, other_depth, rois, context), True),
        (replace(TINY, use_context=False), (color, depth, rois, other_context), True),
        (TINY, (color, other_depth, rois, context), False),
        (TINY, (color, depth, rois, other_context), False),
    ]:
        net = A3DNet(config).eval()
        with torch.no_grad():
            base, moved = net(color, depth, rois, context)[0], net(*changed)[0]
        assert torch.equal(base, moved) == same, config


def test_a_roi_depends_only_on_its_own_image() -> None:
    net = A3DNet(TINY).eval()
    color, depth, rois, context = _inputs()
    with torch.no_grad():
        base = net(color, depth, rois, context)[1]
        color[0] += 5.0
        moved = net(color, depth, rois, context)[1]
    assert torch.equal(base[1:], moved[1:])  # RoIs 1 and 2 are on image 1
    assert not torch.allclose(base[0], moved[0])


@pytest.mark.parametrize("kind", ["align", "max"])
def test_training_step_reaches_both_trunks_and_all_heads(kind: str) -> None:
    torch.manual_seed(0)
    net = A3DNet(NetConfig(width=0.125, fc6=32, fc7=32, fuse_channels=16, roi_pool=kind)).train()
    logits, deltas3d, deltas2d = net(*_inputs())
    loss = torch.nn.functional.cross_entropy(logits, torch.tensor([0, 3, 5])) + deltas3d.square().sum()
    (loss + deltas2d.square().sum()).backward()
    for name in ("color_trunk.features.0.weight", "depth_trunk.features.0.weight", "fuse_roi.weight",
                 "fuse_context.weight", "fc6.weight", "bn7.weight", "cls_score.weight",
                 "bbox_pred_3d.weight", "bbox_pred_2d.weight"):  # fmt: skip
        grad = net.get_parameter(name).grad
        assert grad is not None and grad.abs().max() > 0, name


def test_missing_inputs_are_reported() -> None:
    net = A3DNet(TINY).eval()
    color, depth, rois, context = _inputs()
    with pytest.raises(ValueError, match="depth"):
        net(color, None, rois, context)
    with pytest.raises(ValueError, match="context_rois"):
        net(color, depth, rois, None)


def test_config_validation_presets_and_round_trip() -> None:
    assert preset("vgg16") == NetConfig()
    assert set(PRESETS) == {"vgg16", "vgg16-fused", "cpu-half", "cpu-quarter", "cpu-eighth"}
    assert preset("cpu-eighth").fuse_channels == 64 and preset("cpu-eighth").width == 0.125
    for config in PRESETS.values():  # through the settings codec, as checkpoints store them
        assert apply_plain(NetConfig(), json.loads(json.dumps(plain_from_dataclass(config)))) == config
    with pytest.raises(ValueError, match="unknown network preset 'vgg19'"):
        preset("vgg19")
    with pytest.raises(ValueError, match=r"unknown setting\(s\) depth"):
        apply_plain(NetConfig(), {"width": 0.5, "depth": True})
    for bad in ({"width": 0.0}, {"width": 2.0}, {"fc6": 0}, {"dropout": 1.0}, {"fuse_channels": 0},
                {"roi_pool": "avg"}):  # fmt: skip
        with pytest.raises(ValueError, match="NetConfig"):
            NetConfig(**bad)


def test_trunk_batch_norms_fold_into_the_convs() -> None:
    trunk = VGG16Trunk(0.125, batch_norm=True)
    assert [i for i, _ in trunk.convs()] == list(TORCHVISION_VGG16_CONVS)  # ImageNet keys still map
    trunk.train()
    gen = torch.Generator().manual_seed(3)
    for _ in range(3):  # move the running statistics away from (0, 1)
        trunk(torch.randn(2, 3, 40, 48, generator=gen) * 30 + 10)
    trunk.eval()
    image = torch.randn(1, 3, 40, 48, generator=gen) * 30
    want = trunk(image)
    trunk.fold_batch_norms()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in trunk.modules())
    assert len(trunk.features) == len(VGG16Trunk(0.125).features)
    torch.testing.assert_close(trunk(image), want, rtol=1e-4, atol=1e-4 * want.abs().max().item())
