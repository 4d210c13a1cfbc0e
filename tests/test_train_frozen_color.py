"""A colour trunk of its own width, frozen (solver.freeze_color), its features cached per frame.

The recipe of the real-room model: an ImageNet colour trunk kept fixed beside a small depth trunk
trained from scratch. Checked here on the tiny scenes with small trunks and a fake ImageNet file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from a3d.train.checkpoint import checkpoint_config, load_checkpoint
from a3d.train.cli import main
from a3d.train.color_features import cache_color_features, features_path, trunk_digest
from a3d.train.config import apply_overrides, load_config
from a3d.train.dataset import BatchDataset, compute_target_stats
from a3d.train.loop import param_groups
from a3d.train.model import A3DNet, NetConfig
from a3d.train.model.weights import imagenet_init_state
from a3d.train.roidb import build_roidb
from tests.helpers.train_scenes import TINY, tiny_train_args, write_scenes
from tests.test_weights import fake_vgg16

FROZEN = ("net.color_width=0.125", "solver.freeze_color=13", 'solver.pretrained_trunks=["color"]')


def test_trunks_of_two_widths_fuse_from_the_mean_of_their_leading_channels() -> None:
    net = A3DNet(NetConfig(width=0.0625, trunk_norm=True, color_width=0.25, color_norm=False,
                           fuse_channels=16, fc6=32, fc7=32))  # fmt: skip
    assert (net.color_trunk.out_channels, net.depth_trunk.out_channels) == (128, 32)
    weight = net.fuse_roi.weight[:, :, 0, 0]
    assert torch.equal(weight[:, :16], torch.eye(16) / 2) and torch.equal(
        weight[:, 128:144], torch.eye(16) / 2
    )
    assert weight.abs().sum() == 16
    color, depth = torch.randn(2, 3, 32, 48), torch.randn(2, 3, 32, 48)
    rois = torch.tensor([[0, 1.0, 2.0, 30.0, 20.0], [1, 5.0, 5.0, 40.0, 30.0]])
    logits, d3, d2 = net.eval()(color, depth, rois, rois)
    assert logits.shape == (2, 20) and d3.shape == (2, 140) and d2.shape == (2, 80)
    # the colour trunk's output handed in gives the same answer as the trunk run on the image
    with torch.no_grad():
        again = net(None, depth, rois, rois, net.color_trunk(color))[0]
    torch.testing.assert_close(again, logits)
    with pytest.raises(ValueError, match="trunks of different widths need fuse_channels"):
        A3DNet(NetConfig(width=0.0625, color_width=0.125))


def test_freezing_leading_convs_and_its_limits() -> None:
    net = A3DNet(NetConfig(width=0.0625, color_width=0.125, fuse_channels=8, fc6=16, fc7=16))
    net.freeze_color(5)
    flags = [conv.weight.requires_grad for _, conv in net.color_trunk.convs()]
    assert flags == [False] * 5 + [True] * 8 and not net.color_frozen
    net.freeze_color(13)
    assert net.color_frozen and all(p.requires_grad for p in net.depth_trunk.parameters())
    with pytest.raises(ValueError, match=r"solver.freeze_color=14: expected 0 \.\. 13"):
        net.freeze_color(14)
    with pytest.raises(ValueError, match="must be plain"):
        A3DNet(NetConfig(width=0.0625, trunk_norm=True, fuse_channels=8, fc6=16, fc7=16)).freeze_color(1)


def test_freezing_the_depth_trunks_leading_convs() -> None:
    net = A3DNet(NetConfig(width=0.0625, color_width=0.125, fuse_channels=8, fc6=16, fc7=16))
    net.freeze_depth(10)
    flags = [conv.weight.requires_grad for _, conv in net.depth_trunk.convs()]
    assert flags == [False] * 10 + [True] * 3
    assert all(p.requires_grad for p in net.color_trunk.parameters()) and net.fc6.weight.requires_grad
    trainable = sum(len(group["params"]) for group in param_groups(net, 0.0005))
    assert trainable == sum(p.requires_grad for p in net.parameters()) < len(list(net.parameters()))
    with pytest.raises(ValueError, match=r"solver.freeze_depth=14: expected 0 \.\. 13"):
        net.freeze_depth(14)
    with pytest.raises(ValueError, match=r"net\.trunk_norm=false"):
        A3DNet(NetConfig(width=0.0625, trunk_norm=True, fuse_channels=8, fc6=16, fc7=16)).freeze_depth(1)
    with pytest.raises(ValueError, match="no depth trunk"):
        A3DNet(NetConfig(width=0.0625, use_depth=False, fc6=16, fc7=16)).freeze_depth(1)


def _fake_imagenet(path: Path) -> Path:
    """A small stand-in for the ImageNet file, He-scaled as trained weights are (activations stay O(1))."""
    vgg = fake_vgg16(0.25, fc6=32, fc7=16, seed=2)
    for name, value in vgg.items():
        if name.startswith("features.") and value.ndim == 4:
            value *= (2.0 / value[0].numel()) ** 0.5
    torch.save(vgg, path)
    return path


@pytest.fixture(scope="module")
def frozen_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("frozen")
    frames = write_scenes(root / "frames", 3, seed=4)
    weights = _fake_imagenet(root / "vgg16.pth")
    args = tiny_train_args(frames, root / "run", root / "cache", "solver.iterations=3", "solver.lr_steps=[2]",
                           *FROZEN, f"solver.pretrained={weights}")  # fmt: skip
    assert main(args) == 0
    return root, load_checkpoint(root / "run" / "checkpoint.pt")


def test_a_frozen_trunk_keeps_its_imagenet_weights_while_the_rest_trains(
    frozen_run: tuple[Path, dict],
) -> None:
    root, state = frozen_run
    config = checkpoint_config(root / "run" / "checkpoint.pt", state)
    assert config.solver.freeze_color == 13 and config.net.color_width == 0.125
    net = A3DNet(config.net)
    want = imagenet_init_state(net, torch.load(root / "vgg16.pth", weights_only=True), "vgg16.pth",
                               trunks=("color",))  # fmt: skip
    assert set(want) == {n for n in state["model"] if n.startswith("color_trunk.")}
    for name, value in want.items():
        assert torch.equal(state["model"][name], value), name
    torch.manual_seed(config.solver.seed)
    init = A3DNet(config.net).state_dict()  # the run's own initialisation of the depth trunk
    assert not torch.equal(
        state["model"]["depth_trunk.features.28.weight"], init["depth_trunk.features.28.weight"]
    )
    assert len(list((root / "cache").rglob("*.color-*.npz"))) == 3


def test_cached_features_are_the_trunk_on_each_flip(frozen_run: tuple[Path, dict]) -> None:
    root, state = frozen_run
    config = apply_overrides(load_config("vgg16"), [*TINY, *FROZEN, "data.images_per_batch=1"])
    net = A3DNet(config.net)
    net.load_state_dict(state["model"])
    db = build_roidb(root / "frames", config, root / "cache")
    digest, computed = cache_color_features(db.records, net.color_trunk, config.data.input_scale,
                                            torch.device("cpu"), bf16=False, progress=False)  # fmt: skip
    assert digest == trunk_digest(net.color_trunk) and computed == 0  # the run cached them all
    assert features_path(db.records[0], config.data.input_scale, digest).is_file()
    stats = compute_target_stats(db.records, flip=True)
    cached = BatchDataset(db.records, stats, config, 8, color_features=digest)
    plain = BatchDataset(db.records, stats, config, 8)
    flips = set()
    for iteration in range(8):
        a, b = cached[iteration], plain[iteration]
        assert "color" not in a and "color_map" not in b
        assert torch.equal(a["depth"], b["depth"]) and torch.equal(a["rois"], b["rois"])
        with torch.no_grad():
            want = net.color_trunk.eval()(b["color"])
        np.testing.assert_allclose(a["color_map"], want, rtol=2e-3, atol=2e-3 * float(want.abs().max()))
        flips.add(a["flips"][0])
    assert flips == {False, True}


def test_a_fine_tuned_trunk_learns_at_its_own_lr_multiplier() -> None:
    net = A3DNet(NetConfig(width=0.0625, color_width=0.125, fuse_channels=8, fc6=16, fc7=16))
    net.freeze_color(10)
    trainable = {id(p) for p in net.parameters() if p.requires_grad}
    same = param_groups(net, 0.0005, net.color_trunk, 1.0)
    assert [g["lr_mult"] for g in same] == [1.0, 1.0]  # the two groups of a plain run, as before
    groups = param_groups(net, 0.0005, net.color_trunk, 0.1)
    grouped = [id(p) for g in groups for p in g["params"]]
    assert sorted(grouped) == sorted(trainable)  # every trainable parameter once
    conv5 = {id(conv.weight) for _, conv in net.color_trunk.convs()[10:]}
    slow = {id(p) for g in groups if g["lr_mult"] == 0.1 for p in g["params"]}
    assert conv5 <= slow and slow == {id(p) for p in net.color_trunk.parameters() if p.requires_grad}
    assert all(g["weight_decay"] == (0.0005 if all(p.ndim > 1 for p in g["params"]) else 0.0) for g in groups)


def test_a_zero_multiplier_keeps_the_tuned_convs_while_the_head_trains(tmp_path: Path) -> None:
    frames = write_scenes(tmp_path / "frames", 2, seed=5)
    weights = _fake_imagenet(tmp_path / "vgg16.pth")
    sets = (
        "solver.iterations=2",
        "solver.lr_steps=[]",
        "net.color_width=0.125",
        "solver.freeze_color=10",
        'solver.pretrained_trunks=["color"]',
        f"solver.pretrained={weights}",
        "solver.color_lr_mult=0",
    )
    args = tiny_train_args(frames, tmp_path / "run", tmp_path / "cache", *sets)
    assert main(args) == 0
    state = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    config = checkpoint_config(tmp_path / "run" / "checkpoint.pt", state)
    net = A3DNet(config.net)
    imagenet = imagenet_init_state(
        net, torch.load(weights, weights_only=True), "vgg16.pth", trunks=("color",)
    )
    conv5_3 = "color_trunk.features.28.weight"
    assert torch.equal(state["model"][conv5_3], imagenet[conv5_3])  # tunable, but at lr 0
    torch.manual_seed(config.solver.seed)
    init = A3DNet(config.net).state_dict()
    assert not torch.equal(state["model"]["fc6.weight"], init["fc6.weight"])
