"""TrainConfig: presets, JSON/TOML files, --set overrides, type checks, JSON round trip."""

from __future__ import annotations

import json

import pytest

from a3d.train.config import PRESETS, TrainConfig, apply_overrides, load_config


def test_presets_differ_where_they_should():
    paper, cpu = load_config("vgg16"), load_config("cpu-small")
    assert paper.net.width == 1.0 and paper.data.input_scale == 1.0
    assert (paper.solver.lr, paper.solver.momentum, paper.solver.weight_decay) == (0.005, 0.9, 0.0005)
    assert (paper.data.images_per_batch, paper.data.rois_per_image, paper.data.fg_fraction) == (2, 128, 0.25)
    assert cpu.net.width == 0.25 and cpu.net.fuse_channels is not None
    assert cpu.net.trunk_norm and not paper.net.trunk_norm  # from scratch on CPU vs ImageNet VGG16
    assert cpu.data.input_scale < 1.0 and cpu.solver.iterations < paper.solver.iterations
    assert set(PRESETS) >= {"vgg16", "cpu-small"}


def test_overrides_are_typed():
    config = apply_overrides(
        load_config("vgg16"),
        ["solver.lr=0.01", "solver.iterations=500", "solver.lr_steps=[100, 200]", "data.flip=false",
         "net.fuse_channels=64", "proposals.superpixels.n_segments=80", "data.cache_dir=/tmp/x"],
    )  # fmt: skip
    assert config.solver.lr == 0.01 and isinstance(config.solver.lr, float)
    assert config.solver.iterations == 500 and isinstance(config.solver.iterations, int)
    assert config.solver.lr_steps == (100, 200)
    assert config.data.flip is False
    assert config.net.fuse_channels == 64
    assert config.proposals.superpixels.n_segments == 80
    assert config.data.cache_dir == "/tmp/x"
    assert apply_overrides(config, ["net.fuse_channels=null"]).net.fuse_channels is None
    assert apply_overrides(config, ["solver.lr_steps=300,400"]).solver.lr_steps == (300, 400)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("solver.lrr=1", r"--set solver.lrr=1: unknown setting\(s\) solver.lrr \(known: color_lr_mult, "),
        ("solver.iterations=1.5", "solver.iterations must be an integer, got 1.5"),
        ("data.flip=maybe", "data.flip must be true or false, got 'maybe'"),
        ("solver=3", "solver must be an object, got 3"),
        ("proposals.edge_weights=1,2", r"proposals.edge_weights must be a list of 3 values"),
        ("novalue", "expected KEY=VALUE"),
    ],
)
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(load_config("vgg16"), [override])


def test_files_json_and_toml_with_base_preset(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"preset": "cpu-small", "solver": {"lr": 0.002}}))
    (tmp_path / "b.toml").write_text('preset = "cpu-small"\n[solver]\nlr = 0.002\n[data]\nworkers = 0\n')
    a = load_config(str(tmp_path / "a.json"))
    b = load_config(str(tmp_path / "b.toml"), ["data.workers=0"])
    assert a.net == load_config("cpu-small").net and a.solver.lr == 0.002
    assert b.solver.lr == 0.002 and b.data.workers == 0
    (tmp_path / "bad.json").write_text('{"solver": {"lr": "fast"}}')
    with pytest.raises(ValueError, match=r"bad\.json: solver\.lr must be a finite number, got 'fast'"):
        load_config(str(tmp_path / "bad.json"))
    with pytest.raises(ValueError, match="not a config file nor a preset"):
        load_config(str(tmp_path / "missing.json"))


def test_json_round_trip_is_exact():
    config = apply_overrides(load_config("cpu-small"), ["solver.lr_steps=[7]", "proposals.min_area=20"])
    again = TrainConfig.from_json(config.to_json())
    assert again == config
    assert again.proposals.strategies == config.proposals.strategies  # a tuple of dataclasses


def test_every_network_preset_is_a_config_name():
    """--config takes the network presets too (one table of names): the network is the preset's,
    the schedule the paper's for full-width trunks and cpu-small's at lr 0.005 for narrower ones."""
    from a3d.train.model import PRESETS as NETWORKS

    assert set(NETWORKS) <= set(PRESETS)
    for name, net in NETWORKS.items():
        config = load_config(name)
        assert config.net == net, name
        assert config.solver.lr == 0.005, name  # no BatchNorm in these trunks: the paper's lr
        assert config.data.input_scale == (1.0 if net.width == 1.0 else 0.5), name
    assert load_config("vgg16-fused").solver.iterations == load_config("vgg16").solver.iterations
    with pytest.raises(ValueError, match=r"vgg19: not a config file nor a preset \(vgg16, .*, vgg16-fused, "):
        load_config("vgg19")
