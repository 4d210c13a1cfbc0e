"""ImageNet VGG16 loading (a3d.train.model.weights) from small fake files and full-shape meta tensors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from a3d.train.model.config import NetConfig, preset
from a3d.train.model.net import A3DNet
from a3d.train.model.vgg import VGG16_LAYOUT, scaled_channels
from a3d.train.model.weights import imagenet_init_state, load_vgg16_imagenet

TV_STD = torch.tensor([0.229, 0.224, 0.225])
SMALL = NetConfig(width=0.125, fc6=32, fc7=16)  # blocks of 64 x 7 x 7, four of them


def fake_vgg16(
    width: float, fc6: int, fc7: int, seed: int = 0, device: str = "cpu"
) -> dict[str, torch.Tensor]:
    """A torchvision-layout VGG16 state dict with width-scaled convs and fc6 of fc6 x (C5 x 7 x 7)."""
    gen = torch.Generator().manual_seed(seed) if device == "cpu" else None

    def rand(*shape: int) -> torch.Tensor:
        return torch.empty(*shape, device=device) if gen is None else torch.randn(*shape, generator=gen)

    state, index, in_channels = {}, 0, 3
    for item in VGG16_LAYOUT:
        if item == "M":
            index += 1
            continue
        out = scaled_channels(int(item), width)
        state[f"features.{index}.weight"] = rand(out, in_channels, 3, 3)
        state[f"features.{index}.bias"] = rand(out)
        index, in_channels = index + 2, out
    state["classifier.0.weight"] = rand(fc6, in_channels * 49)
    state["classifier.0.bias"] = rand(fc6)
    state["classifier.3.weight"] = rand(fc7, fc6)
    state["classifier.3.bias"] = rand(fc7)
    state["classifier.6.weight"] = rand(1000, fc7)
    state["classifier.6.bias"] = rand(1000)
    return state


def _save(tmp_path: Path, state: object) -> Path:
    path = tmp_path / "vgg16.pth"
    torch.save(state, path)
    return path


def test_exact_size_file_loads_into_both_trunks_and_fc(tmp_path: Path) -> None:
    vgg = fake_vgg16(0.125, fc6=32, fc7=16)
    net = A3DNet(SMALL)
    untouched = net.cls_score.weight.clone()
    loaded = load_vgg16_imagenet(net, _save(tmp_path, vgg))
    assert len(loaded) == 2 * 2 * 13 + 4
    for trunk in (net.color_trunk, net.depth_trunk):
        for index, conv in trunk.convs()[1:]:
            assert torch.equal(conv.weight, vgg[f"features.{index}.weight"])
            assert torch.equal(conv.bias, vgg[f"features.{index}.bias"])
    # conv1_1 on our BGR 0..255 input == torchvision's conv1_1 on the same image normalised its way.
    gen = torch.Generator().manual_seed(5)
    bgr = torch.randn(1, 3, 8, 9, generator=gen) * 60
    rgb_normalised = bgr.flip(1) / (255 * TV_STD[:, None, None])
    conv1 = vgg["features.0.weight"], vgg["features.0.bias"]
    want = torch.nn.functional.conv2d(rgb_normalised, *conv1, padding=1)
    torch.testing.assert_close(net.depth_trunk.features[0](bgr), want, rtol=1e-5, atol=1e-4)
    # Four identical pooled blocks through fc6 == ImageNet fc6 of one block.
    block = torch.randn(3, 64 * 49, generator=gen)
    torch.testing.assert_close(
        net.fc6(block.repeat(1, 4)),
        torch.nn.functional.linear(block, vgg["classifier.0.weight"], vgg["classifier.0.bias"]),
        rtol=1e-5,
        atol=1e-4,
    )
    assert torch.equal(net.fc7.weight, vgg["classifier.3.weight"])
    assert torch.equal(net.cls_score.weight, untouched)


def test_larger_file_gives_scaled_leading_slices(tmp_path: Path) -> None:
    vgg = fake_vgg16(0.25, fc6=48, fc7=24, seed=1)
    net = A3DNet(SMALL)
    load_vgg16_imagenet(net, _save(tmp_path, vgg), input_convention="caffe")
    assert torch.equal(net.color_trunk.features[0].weight, vgg["features.0.weight"][:8])  # caffe: as is
    conv = net.color_trunk.features[7]  # conv2_2: 16 of 32 outputs, 16 of 32 inputs, x 2
    torch.testing.assert_close(conv.weight, vgg["features.7.weight"][:16, :16] * 2)
    torch.testing.assert_close(conv.bias, vgg["features.7.bias"][:16])
    file_fc6 = vgg["classifier.0.weight"].reshape(48, 128, 7, 7)[:32, :64].reshape(32, -1)
    torch.testing.assert_close(net.fc6.weight, (file_fc6 * 2 / 4).repeat(1, 4))
    torch.testing.assert_close(net.fc7.weight, vgg["classifier.3.weight"][:16, :32] * 48 / 32)


@pytest.mark.parametrize("name", ["vgg16", "vgg16-fused", "cpu-half", "cpu-eighth"])
def test_full_size_vgg16_maps_onto_every_preset(name: str) -> None:
    """Real VGG16 shapes (meta tensors, nothing allocated) -> every trunk conv, fc6 and fc7."""
    with torch.device("meta"):
        net = A3DNet(preset(name))
    entries = imagenet_init_state(net, fake_vgg16(1.0, 4096, 4096, device="meta"), "vgg16.pth")
    params = dict(net.named_parameters())
    trunk_params = {n for n in params if "trunk" in n}
    assert len(trunk_params) == 52
    assert trunk_params | {"fc6.weight", "fc6.bias", "fc7.weight", "fc7.bias"} == set(entries)
    assert all(entries[n].shape == params[n].shape for n in entries)


def test_fc_layers_keep_their_init_when_shapes_do_not_allow_a_slice() -> None:
    vgg = fake_vgg16(1.0, 4096, 4096, device="meta")
    for config in (NetConfig(fc6=8192), NetConfig(pool_size=5), NetConfig(fuse_channels=1024)):
        with torch.device("meta"):
            net = A3DNet(config)
        entries = imagenet_init_state(net, vgg, "vgg16.pth")
        assert not any(n.startswith("fc") for n in entries) and len(entries) == 52


def test_bad_files_are_reported_with_the_file_and_key(tmp_path: Path) -> None:
    net = A3DNet(SMALL)
    vgg = fake_vgg16(0.125, fc6=32, fc7=16)
    missing = {k: v for k, v in vgg.items() if k != "features.12.weight"}
    with pytest.raises(ValueError, match=r"vgg16\.pth: missing key 'features\.12\.weight'"):
        load_vgg16_imagenet(net, _save(tmp_path, missing))
    too_small = r"vgg16\.pth: 'features\.14\.weight' has shape \(16, 32, 3, 3\), the model needs \(32, 32"
    with pytest.raises(ValueError, match=too_small):
        load_vgg16_imagenet(net, _save(tmp_path, {**vgg, "features.14.weight": torch.zeros(16, 32, 3, 3)}))
    with pytest.raises(ValueError, match="3x3 kernels"):
        load_vgg16_imagenet(net, _save(tmp_path, {**vgg, "features.0.weight": torch.zeros(8, 3, 5, 5)}))
    with pytest.raises(ValueError, match="not C x 7 x 7"):
        load_vgg16_imagenet(net, _save(tmp_path, {**vgg, "classifier.0.weight": torch.zeros(32, 100)}))
    with pytest.raises(ValueError, match="holds a list"):
        load_vgg16_imagenet(net, _save(tmp_path, [1, 2]))
    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"garbage\.pth: not a torch state dict"):
        load_vgg16_imagenet(net, garbage)
    with pytest.raises(FileNotFoundError, match=r"nowhere\.pth"):
        load_vgg16_imagenet(net, tmp_path / "nowhere.pth")
