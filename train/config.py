"""Training configuration: one typed dataclass tree, named presets, config files and overrides.

A run is described by ``TrainConfig``: the network (``NetConfig`` of a3d.train.model), the
proposal stage (``ProposalConfig`` of a3d.runtime.frontend.proposals), RoI sampling and augmentation,
the solver, logging/validation, and inference post-processing. It is built by

    preset (``PRESETS``: vgg16, the CPU presets, every network preset)  ->  config file (JSON or
    TOML)  ->  ``--set a.b=value``

each layer overriding the previous one key by key. A config file may name its base preset with a
top-level ``"preset"`` key. Values are checked against the dataclass field types by the settings
codec the model file's settings use too (a3d.runtime.io.plain_config); an unknown key or a wrong
type is a one-line ``ValueError`` naming the key (and the file).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from a3d.runtime.frontend.proposals import ProposalConfig
from a3d.runtime.io.plain_config import apply_plain, plain_from_dataclass
from a3d.runtime.pipeline import PipelineConfig
from a3d.train.model import NetConfig
from a3d.train.model.config import PRESETS as NETWORK_PRESETS


@dataclass
class DataConfig:
    """RoI database, mini-batch sampling (docs/conventions.md "Training") and input preparation.

    ``input_scale`` resizes colour and depth (and every 2D box) before the network: 1.0 is the
    native frame size, as in the paper; CPU presets train at a reduced scale. Proposals, lifting
    and all 3D geometry always work at native resolution (a3d.runtime.network.network_input).
    """

    input_scale: float = PipelineConfig.input_scale
    context_scale: float = PipelineConfig.context_scale  # context box = RoI scaled about its centre, clipped
    flip: bool = True
    augment: bool = False  # colour and depth augmentation per training image (a3d.train.augment)
    images_per_batch: int = 2
    group_by_shape: bool = True  # batch frames of one size together (less padding; a3d.train.sampler)
    rois_per_image: int = 128
    fg_fraction: float = 0.25
    fg_iou: float = 0.5  # foreground: 2D IoU >= fg_iou with a visible (gt2d_sel) box
    detector_rois: int = 0  # per visible box, RoIs jittered as a 2D detector's (a3d.train.detector_rois)
    bg_iou_low: float = 0.1  # background: IoU in [bg_iou_low, fg_iou)
    depth_truncation_m: float = PipelineConfig.depth_truncation_m  # metres mapped to 255 (depth input)
    workers: int = 1  # DataLoader worker processes (0: load in the training process)
    cache_dir: str = ""  # per-frame proposal cache; "" = RUN_DIR/cache
    front_end_workers: int = 0  # processes computing uncached proposals for the RoI database; 0 = all cores


PRECISIONS = ("fp32", "bf16")  # SolverConfig.precision's values


@dataclass
class SolverConfig:
    """SGD with momentum and Caffe "step" decay (docs/conventions.md "Training").

    ``precision`` "bf16" runs the forward pass and the loss under bfloat16 autocast (weights,
    gradients and the optimizer stay float32): on a CPU with AMX or AVX-512 BF16 it trains about
    twice as fast as "fp32"; on a CPU without them bfloat16 is emulated and slower (a3d-train says so).
    ``minutes`` > 0 fits the run to that wall-clock budget on this machine (a3d.train.budget):
    ``iterations`` is then the ceiling and ``lr_steps`` scale with the fitted length.
    ``freeze_color`` keeps the colour trunk's first N convolutions at their initial (ImageNet)
    weights; with all 13 frozen and ``data.augment`` off, the trunk's features are computed once
    per frame and cached (a3d.train.color_features), so training runs the depth trunk and the
    head alone. ``freeze_depth`` keeps the depth trunk's first N convolutions at the weights the
    run starts from (``init``): a fine-tune on one room's frames (a3d-finetune) moves the rest.
    ``frozen_norms`` keeps every BatchNorm in eval mode while training (its statistics
    fixed, its scale and shift still trained): a network read back from a model file, whose
    statistics were folded into the weights (a3d.export.read_back), fine-tunes without them moving.
    """

    iterations: int = 40000
    lr: float = 0.005
    momentum: float = 0.9
    weight_decay: float = 0.0005
    lr_steps: tuple[int, ...] = (30000,)  # lr *= gamma at each of these iterations
    gamma: float = 0.1
    lambda_3d: float = 1.0
    lambda_2d: float = 1.0
    seed: int = 0
    precision: str = "fp32"  # "fp32" or "bf16" (autocast; see above)
    minutes: float = 0.0  # wall-clock budget of the run; 0 = run ``iterations`` (see above)
    threads: int = 0  # torch intra-op threads of the training process; 0 = torch's default
    pretrained: str = ""  # torchvision-layout VGG16 ImageNet state dict; "" = random initialisation
    pretrained_trunks: tuple[str, ...] = ("color", "depth")  # the trunks ``pretrained`` initialises
    freeze_color: int = 0  # leading colour-trunk convs kept fixed; 13 = all (features cached, see below)
    freeze_depth: int = 0  # leading depth-trunk convs kept fixed (a fine-tune from solver.init)
    color_lr_mult: float = 1.0  # lr factor of the colour trunk's trainable convs (fine-tuning ImageNet: 0.1)
    init: str = ""  # a3d-train checkpoint to fine-tune: its weights, target statistics and mean sizes
    frozen_norms: bool = False  # BatchNorms keep their running statistics while training (see below)


@dataclass
class LogConfig:
    """Progress, metrics, checkpoints and periodic validation."""

    log_every: int = 20  # iterations per metrics.jsonl line
    checkpoint_every: int = 1000
    val_every: int = 0  # 0: validate only at the end (when validation data is given)
    val_frames: int = 0  # 0: all validation frames
    progress: bool = True  # tqdm bar on stderr


@dataclass
class InferenceConfig:
    """Post-processing (docs/conventions.md "Inference and post-processing"); the runtime's defaults."""

    top_k: int = PipelineConfig.top_k  # detections kept per class and image before NMS
    nms_iou: float = PipelineConfig.nms_iou  # 2D NMS on the proposal boxes, per class
    min_score: float = PipelineConfig.min_score  # detections below this score are dropped (0: none)
    regress_3d: bool = True  # False: zero 3D deltas, i.e. the initial boxes (the "-3dreg" ablation)


@dataclass(frozen=True)
class PretrainConfig:
    """Schedule of a3d-pretrain (a3d.train.pretrain; the network's shape comes from a NetConfig)."""

    iterations: int = 3000
    batch: int = 64
    lr: float = 0.02
    lr_step: float = 0.75  # lr *= 0.1 after this share of the iterations
    momentum: float = 0.9
    weight_decay: float = 0.0005
    crop: int = 112
    val_share: float = 0.1  # frames held out for validation accuracy
    seed: int = 0


@dataclass
class TrainConfig:
    net: NetConfig = field(default_factory=NetConfig)
    proposals: ProposalConfig = field(default_factory=ProposalConfig)
    data: DataConfig = field(default_factory=DataConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    log: LogConfig = field(default_factory=LogConfig)
    inference: InferenceConfig = field(default_factory=InferenceConfig)

    def to_dict(self) -> dict:
        return plain_from_dataclass(self)

    def pipeline(self, mean_sizes: np.ndarray) -> PipelineConfig:
        """The runtime pipeline's settings for this model (what the exported model's metadata holds)."""
        return PipelineConfig(
            mean_sizes=np.asarray(mean_sizes, np.float64),
            proposals=self.proposals,
            input_scale=self.data.input_scale,
            context_scale=self.data.context_scale,
            depth_truncation_m=self.data.depth_truncation_m,
            top_k=self.inference.top_k,
            nms_iou=self.inference.nms_iou,
            min_score=self.inference.min_score,
        )

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, values: Mapping, where: str = "config") -> TrainConfig:
        return apply_values(cls(), values, where)

    @classmethod
    def from_json(cls, text: str, where: str = "config") -> TrainConfig:
        return cls.from_dict(json.loads(text), where)


def _vgg16() -> TrainConfig:
    """The paper's model and schedule: full VGG16 trunks at native size, 40k iterations."""
    return TrainConfig(net=NETWORK_PRESETS["vgg16"])


def _cpu_small() -> TrainConfig:
    """Quarter-width trunks with BatchNorm, fused to 128 channels, fc 512, at input scale 0.5: a
    model that trains from scratch on 2 CPU cores. On 1050 a3d-synth frames the 5000 iterations
    take 41 minutes with the RoI database (2.3 iterations per second) and reach mAP@0.25 42.6 on
    350 held-out frames. BatchNorm (folded at export) is what lets lr 0.02 train from scratch;
    without it, lr 0.005 reached 27.8 on a smaller set in 3000 iterations."""
    return apply_values(
        TrainConfig(),
        {
            "net": {"width": 0.25, "fuse_channels": 128, "fc6": 512, "fc7": 512, "trunk_norm": True},
            "data": {"input_scale": 0.5, "workers": 1},
            "solver": {"iterations": 5000, "lr": 0.02, "lr_steps": [3800]},
            "log": {"log_every": 10, "checkpoint_every": 500, "val_every": 1000},
        },
        "preset cpu-small",
    )


def _cpu_tiny() -> TrainConfig:
    """cpu-small's network on a schedule for the first hour: 1500 iterations (lr x0.1 at the same
    0.76 of the run), checkpoints every 250, validation on 50 frames at the end only; about 11
    minutes on 2 idle CPU cores (cpu-small's 2.3 iterations per second; docs/first-hour.md)."""
    return apply_values(
        _cpu_small(),
        {
            "solver": {"iterations": 1500, "lr_steps": [1140]},
            "log": {"checkpoint_every": 250, "val_every": 0, "val_frames": 50},
        },
        "preset cpu-tiny",
    )


def _cpu_imagenet() -> TrainConfig:
    """The real-room recipe: cpu-small's depth trunk and head beside a full-width colour trunk that
    keeps ImageNet VGG16's weights (``--set solver.pretrained=FILE``, a3d-vgg16-weights), frozen, its
    features computed once per frame (a3d.train.color_features), so the CPU trains the rest."""
    return apply_values(
        _cpu_small(),
        {
            "net": {"color_width": 1.0, "color_norm": False},
            "solver": {"freeze_color": 13, "pretrained_trunks": ["color"]},
        },
        "preset cpu-imagenet",
    )


def _for_network(name: str) -> TrainConfig:
    """A network preset of a3d.train.model with a schedule that suits it: full-width trunks the
    paper's (as vgg16: native size, lr 0.005, 40k iterations); width-scaled trunks cpu-small's input
    scale and iterations at the paper's lr 0.005, since their trunks have no BatchNorm (cpu-small's
    lr 0.02 trains from scratch only with it: README "Where a3d departs from the paper")."""
    net = NETWORK_PRESETS[name]
    if net.width == 1.0:
        return TrainConfig(net=net)
    return replace(apply_values(_cpu_small(), {"solver": {"lr": 0.005}}, f"preset {name}"), net=net)


PRESETS: dict[str, Callable[[], TrainConfig]] = {
    "vgg16": _vgg16,
    "cpu-small": _cpu_small,
    "cpu-tiny": _cpu_tiny,
    "cpu-imagenet": _cpu_imagenet,
    **{name: partial(_for_network, name) for name in NETWORK_PRESETS if name != "vgg16"},
}
"""Every name ``--config`` takes: the training presets, then each network preset of
a3d.train.model (``vgg16-fused``, ``cpu-half``, ...) with a schedule that suits it."""
GPU_PRESET = "vgg16"  # a3d-train's default on a CUDA device
CPU_PRESET = "cpu-small"  # ... and without one


def load_config(source: str | None = None, overrides: list[str] | tuple[str, ...] = ()) -> TrainConfig:
    """Build a config from a preset name or a JSON/TOML file (default: ``vgg16``), then ``k=v`` overrides."""
    config = _load_source(source or "vgg16")
    return apply_overrides(config, overrides)


def apply_overrides(config: TrainConfig, overrides: list[str] | tuple[str, ...]) -> TrainConfig:
    """Apply ``a.b=value`` strings; value is JSON when it parses (numbers, true, [1, 2]) else a string."""
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set {item!r}: expected KEY=VALUE, e.g. solver.lr=0.001")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        nested: dict = {}
        node = nested
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
        config = apply_values(config, nested, f"--set {item}")
    return config


def _load_source(source: str) -> TrainConfig:
    if source in PRESETS:
        return PRESETS[source]()
    path = Path(source)
    if not path.is_file():
        raise ValueError(f"{source}: not a config file nor a preset ({', '.join(PRESETS)})")
    try:
        text = path.read_text(encoding="utf-8")
        values = _parse_toml(text) if path.suffix == ".toml" else json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as e:  # JSON and TOML errors are ValueErrors
        raise ValueError(f"{path}: cannot read config ({e})") from None
    if not isinstance(values, dict):
        raise ValueError(f"{path}: a config file must hold an object/table at the top level")
    values = dict(values)
    base = values.pop("preset", "vgg16")
    if base not in PRESETS:
        raise ValueError(f"{path}: unknown preset {base!r} (known: {', '.join(PRESETS)})")
    return apply_values(PRESETS[base](), values, str(path))


def _parse_toml(text: str) -> dict:
    try:
        import tomllib  # Python >= 3.11
    except ImportError:
        raise ValueError("TOML config files need Python 3.11 or newer; use JSON") from None
    return tomllib.loads(text)


def apply_values(obj, values: Mapping, where: str):
    """A copy of dataclass ``obj`` with ``values`` (nested mappings) applied, each value read as its
    field's type (a3d.runtime.io.plain_config, lenient: also strings); ValueError "WHERE: ...".
    """
    try:
        return apply_plain(obj, values, lenient=True, error=ValueError)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
