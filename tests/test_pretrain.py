"""a3d-pretrain (a3d.train.pretrain): crops, the torchvision-layout file and what loads back from it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from a3d.synth.cli import main as synth_main
from a3d.train.model.config import NetConfig
from a3d.train.model.net import A3DNet
from a3d.train.model.weights import load_vgg16_imagenet
from a3d.train.pretrain import BACKGROUND_MAX_IOU, CropClassifier, frame_crops, torchvision_state
from a3d.train.pretrain_cli import main
from tests.helpers.train_scenes import write_scenes

TINY = NetConfig(width=0.0625, fc6=32, fc7=16, trunk_norm=True, dropout=0.0)


def _randomise_batch_norms(model: torch.nn.Module, seed: int) -> None:
    """Non-trivial running statistics and affine parameters, so that folding them matters."""
    gen = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            n = m.num_features
            m.running_mean.copy_(torch.randn(n, generator=gen))
            m.running_var.copy_(torch.rand(n, generator=gen) + 0.5)
            m.weight.data.copy_(torch.rand(n, generator=gen) + 0.5)
            m.bias.data.copy_(torch.randn(n, generator=gen) * 0.1)


def test_the_file_loads_into_both_trunks_as_the_trained_trunk(tmp_path):
    """BatchNorm folded and conv1_1 converted to torchvision's convention: the loader's conversion
    gives back a plain trunk that computes what the trained BN trunk computes in eval mode."""
    torch.manual_seed(0)
    classifier = CropClassifier(TINY, crop=112).eval()
    _randomise_batch_norms(classifier, seed=1)
    path = tmp_path / "synth-vgg16.pt"
    torch.save(torchvision_state(classifier), path)

    net = A3DNet(NetConfig(width=0.0625, fc6=32, fc7=16, fuse_channels=None)).eval()
    loaded = load_vgg16_imagenet(net, path)
    assert any(name.startswith("depth_trunk.") for name in loaded) and "fc7.weight" in loaded
    image = torch.randn(2, 3, 64, 80) * 50  # a3d's colour input scale (BGR minus mean)
    with torch.no_grad():
        want = classifier.trunk(image)
        for trunk in (net.color_trunk, net.depth_trunk):
            assert torch.allclose(trunk(image), want, rtol=1e-4, atol=1e-4 * want.abs().max().item())
        assert torch.equal(net.fc7.weight, classifier.classifier[3].weight)


def test_background_crops_stay_off_the_objects():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    boxes = np.array([[10.0, 10, 60, 70], [80, 20, 150, 90], [5, 100, 9, 110]])  # the last is too small
    crops, labels = [], []
    for _ in range(40):
        c, lab = frame_crops(image, boxes, np.array([4, 0, 7]), 24, rng)
        crops += c
        labels += lab
    labels = np.array(labels)
    assert all(c.shape == (24, 24, 3) for c in crops)
    assert np.sum(labels == 5) == np.sum(labels == 1) == 40 and not np.any(labels == 8)
    assert 0 < np.sum(labels == 0) < 40  # about BACKGROUND_SHARE of the 80 object crops
    assert BACKGROUND_MAX_IOU < 0.5


@pytest.mark.slow  # a pretraining run
def test_cli_learns_the_crops_and_writes_the_torchvision_layout(tmp_path, capsys):
    assert synth_main([str(tmp_path / "synth"), "--frames", "3", "--seed", "5", "--split", "test=0"]) == 0
    out = tmp_path / "w" / "synth.pt"
    sets = ("net.width=0.0625", "net.fc6=32", "net.fc7=32", "net.trunk_norm=true", "net.dropout=0",
            "net.pool_size=2")  # a 32-pixel crop's conv5_3 is 2 x 2  # fmt: skip
    flags = "--iters 100 --batch 16 --crop 32 --lr 0.02 --val-share 0 --device cpu".split()
    code = main([str(tmp_path / "synth" / "train"), "--out", str(out), "--config", "vgg16",
                 *[a for s in sets for a in ("--set", s)], *flags])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    report = json.loads((tmp_path / "w" / "synth.pt.json").read_text())
    assert report["train_crops"] >= 20 and report["val_crops"] == 0
    assert report["first_loss"] > 2.5  # about ln 20 at the start
    assert report["last_loss"] < 0.75 * report["first_loss"]  # it learns the crops' labels
    state = torch.load(out, weights_only=True)
    assert state["features.28.weight"].shape == (32, 32, 3, 3)  # conv5_3 at width 1/16, BN folded away
    assert not any(".running_mean" in key for key in state)
    assert state["classifier.0.weight"].shape == (32, 32 * 2 * 2)
    assert state["classifier.6.weight"].shape == (20, 32)  # background + 19 classes
    assert not list(out.parent.glob(".*tmp*"))


@pytest.mark.parametrize("make", ["missing", "no-gt"])
def test_cli_errors_are_one_line(tmp_path, capsys, make):
    folder = tmp_path / "frames"
    if make == "no-gt":
        write_scenes(folder, 1, seed=2)
        for gt in folder.glob("*.gt.json"):
            gt.unlink()
    out = tmp_path / "w.pt"
    code = main([str(folder), "--out", str(out), "--config", "vgg16", "--set", "net.width=0.0625"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and str(folder) in err
    assert not (tmp_path / "w.pt").exists()
