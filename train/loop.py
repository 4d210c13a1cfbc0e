"""The SGD training loop: data, model, optimisation, metrics, checkpoints, validation, resume.

docs/conventions.md "Training": SGD with momentum 0.9, weight decay 0.0005 (on weights; biases and
BatchNorm parameters are not decayed, as in the Caffe VGG16 models), base lr 0.005, the lr
times ``gamma`` at each of ``lr_steps`` (Caffe "multistep"); 2 images x 128 RoIs, 25% foreground.

Reproducibility: the model is initialised from ``solver.seed``; the mini-batch of iteration i
(images, flips, RoIs) is a pure function of (seed, i, rank) (a3d.train.sampler), and the global
torch RNG (dropout) is reseeded from (seed, i, rank) at every iteration. A checkpoint therefore
needs no RNG state: weights, optimizer state (momentum) and the iteration determine the rest,
and a run resumed from any checkpoint ends with weights bit-identical to an uninterrupted run
(on CPU, with the same thread count; CUDA kernels may be non-deterministic).

Outputs in the run folder: ``config.json`` (the resolved TrainConfig), ``checkpoint.pt``
(a3d.train.checkpoint, every ``log.checkpoint_every`` iterations and at the end),
``metrics.jsonl`` (one JSON object per line with ``kind`` and ``iter``: "data" the RoI database,
"train" the mean loss terms, lr and speed over the last ``log.log_every`` iterations, "val" the
validation mAP, "sync" the ranks' parameter digests under DDP, "plan" each fit of a time budget,
a3d.train.budget),
``loss.png`` (loss curves and validation mAP), and ``cache/`` (per-frame proposals) unless
``data.cache_dir`` points elsewhere.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from a3d.runtime.frontend.working_size import WORKING_SIDE
from a3d.runtime.io.atomic import atomic_write_bytes
from a3d.runtime.network.cpu_support import bf16_instructions
from a3d.runtime.structures.classes import CLASSES
from a3d.train.budget import END_SECONDS, PLAN_AFTER, REFIT_EVERY, WARMUP, fit_schedule
from a3d.train.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_trained_state,
    load_weights,
    save_checkpoint,
)
from a3d.train.color_features import cache_color_features
from a3d.train.config import PRECISIONS, SolverConfig, TrainConfig
from a3d.train.dataset import BatchDataset, TargetStats, batch_loader, compute_target_stats
from a3d.train.distributed import (
    DistInfo,
    barrier,
    check_in_sync,
    init_distributed,
    local_device,
    mean_over_ranks,
    shutdown,
    unwrap,
    wrap_model,
)
from a3d.train.inference import TorchDetector, validate
from a3d.train.losses import LossTerms, detection_loss
from a3d.train.model import A3DNet, describe_loaded, load_vgg16_imagenet
from a3d.train.roidb import Folders, build_roidb, describe

logger = logging.getLogger(__name__)

CHECKPOINT_NAME = "checkpoint.pt"
METRICS_NAME = "metrics.jsonl"
PLOT_NAME = "loss.png"
CONFIG_NAME = "config.json"
_DROPOUT_STREAM = 2  # seed stream (see sampler's 0 and 1)
_POSTFIX = (("loss", "loss"), ("cls", "loss_cls"), ("l3d", "loss_3d"), ("l2d", "loss_2d"))  # progress bar


@dataclass
class TrainResult:
    run_dir: Path
    iteration: int
    last_loss: float | None
    val_map: float | None  # mAP@0.25 over the 19 classes at the last validation (None: none run)


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped the loop after a whole iteration, whose checkpoint is saved."""


class _StopRequest:
    """While the loop runs, SIGINT and SIGTERM ask it to stop at the end of the iteration (a
    checkpoint taken mid-step would hold half-updated weights); a second signal stops at once.

    Only in a single process on the main thread: under DDP every rank would have to agree on the
    iteration to stop at, so there the periodic checkpoints are what --resume continues from.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and threading.current_thread() is threading.main_thread()
        self.requested = False
        self._previous: dict[int, object] = {}

    def __enter__(self) -> _StopRequest:
        if self.enabled:
            self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum: int, _frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        name = signal.Signals(signum).name
        logger.warning(
            "%s: stopping after this iteration to save a checkpoint (again: stop now, unsaved)", name
        )


def resolve_device(name: str | None) -> torch.device:
    """``None``: CUDA when available, else CPU."""
    if name is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {name}: CUDA is not available on this machine")
    return device


def lr_at(iteration: int, solver: SolverConfig) -> float:
    """Learning rate of (0-based) ``iteration``: lr * gamma ** (number of steps passed)."""
    return solver.lr * solver.gamma ** sum(iteration >= s for s in solver.lr_steps)


def iteration_seed(seed: int, iteration: int, rank: int) -> int:
    """The torch seed of one iteration on one rank (dropout masks)."""
    return int(np.random.SeedSequence([seed, _DROPOUT_STREAM, iteration, rank]).generate_state(1)[0])


def param_groups(
    model: torch.nn.Module, weight_decay: float, slow: torch.nn.Module | None = None, lr_mult: float = 1.0
) -> list[dict]:
    """Weights decayed; biases and BatchNorm scales/shifts (1-D parameters) not. The trainable
    parameters of ``slow`` (an ImageNet trunk being fine-tuned) get groups of their own that learn at
    ``lr_mult`` times the lr (each group's "lr_mult"), so a head's lr does not wash out what the trunk
    learnt on real images."""
    slow_ids = {id(p) for p in slow.parameters()} if slow is not None and lr_mult != 1.0 else set()
    trainable = [p for p in model.parameters() if p.requires_grad]
    parts = [(1.0, [p for p in trainable if id(p) not in slow_ids])]
    if any(id(p) in slow_ids for p in trainable):
        parts.append((lr_mult, [p for p in trainable if id(p) in slow_ids]))
    return [
        {
            "params": [p for p in params if (p.ndim > 1) == decayed],
            "weight_decay": weight_decay if decayed else 0.0,
            "lr_mult": mult,
        }
        for mult, params in parts
        for decayed in (True, False)
    ]


class MetricsLog:
    """metrics.jsonl, append-only; a resumed run first drops the lines past its checkpoint."""

    def __init__(self, path: Path, keep_until: int | None) -> None:
        self.path = path
        kept = [r for r in read_metrics(path) if keep_until is not None and r.get("iter", 0) <= keep_until]
        atomic_write_bytes(path, "".join(json.dumps(r) + "\n" for r in kept).encode())

    def write(self, record: dict) -> None:
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(record) + "\n")


def read_metrics(path: str | os.PathLike) -> list[dict]:
    """The records of a metrics.jsonl (a torn last line, from a kill, is ignored)."""
    path = Path(path)
    if not path.is_file():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def plot_losses(metrics_path: Path, png_path: Path) -> None:
    """Loss terms (log scale) against iterations, validation mAP@0.25 on a second axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = read_metrics(metrics_path)
    train = [r for r in records if r.get("kind") == "train"]
    val = [r for r in records if r.get("kind") == "val"]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for key in ("loss", "loss_cls", "loss_3d", "loss_2d"):
        points = [(r["iter"], r[key]) for r in train if r.get(key, 0) > 0]
        if points:
            ax.plot(*zip(*points, strict=True), label=key, linewidth=1.5 if key == "loss" else 1.0)
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    if train:
        ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if val:
        ax2 = ax.twinx()
        ax2.plot([r["iter"] for r in val], [100 * r["map25"] for r in val], "k.--", label="val mAP@0.25")
        ax2.set_ylabel("mAP@0.25 (%)")
        ax2.set_ylim(bottom=0)
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    if handles:  # below the axes: inside, it hid the last validation marker (upper right)
        ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=len(handles),
                  fontsize=8, frameon=False)  # fmt: skip
    fig.tight_layout()
    tmp = png_path.with_name(f".{png_path.name}.tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, png_path)


def _to_device(batch: dict, device: torch.device) -> dict:
    return {k: v.to(device, non_blocking=True) if torch.is_tensor(v) else v for k, v in batch.items()}


def forward_loss(net: torch.nn.Module, batch: dict, solver: SolverConfig, bf16: bool) -> LossTerms:
    """The network on one mini-batch (already on its device) and its loss; ``bf16``: the forward
    pass under bfloat16 autocast, the loss on its outputs in float32 (SolverConfig.precision)."""
    device = batch["depth"].device.type
    with torch.autocast(device, dtype=torch.bfloat16, enabled=bf16):
        outputs = net(batch.get("color"), batch["depth"], batch["rois"], batch["context_rois"],
                      batch.get("color_map"))  # fmt: skip
    logits, deltas3d, deltas2d = (x.float() for x in outputs)
    return detection_loss(logits, deltas3d, deltas2d, batch["labels"], batch["targets3d"], batch["targets2d"],
                          batch["weights3d"], solver.lambda_3d, solver.lambda_2d)  # fmt: skip


def train(
    data: Folders,
    run_dir: str | os.PathLike,
    config: TrainConfig,
    *,
    device: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    val_data: str | os.PathLike | None = None,
) -> TrainResult:
    """Train on the annotated frames of ``data`` (a frame folder, or several: your camera's frames
    beside synthetic ones, say) into ``run_dir`` (see the module docstring).

    ``resume``: continue from ``run_dir/checkpoint.pt`` (``config`` should be the checkpoint's,
    see a3d.train.cli). Without it, a run in ``run_dir`` (a checkpoint or metrics) is an error,
    unless ``overwrite``: then its checkpoint, metrics and plot are deleted first.
    ``val_data``: annotated frames scored every ``log.val_every`` iterations and at the end.
    Ctrl-C or SIGTERM (single process) stops after the current iteration with its checkpoint
    saved, raising ``TrainingInterrupted``.
    """
    dev = resolve_device(device)
    info = init_distributed(dev)
    try:
        dev = local_device(dev, info)
        result = _Run(data, Path(run_dir), config, dev, info, resume, overwrite, val_data).loop()
        barrier(info)  # no rank tears its gloo connections down while another still uses them
        return result
    finally:
        shutdown(info)


class _Run:
    """One training run: its state (model, optimizer, data) and the loop over iterations."""

    def __init__(self, data: Folders, run: Path, config: TrainConfig, dev: torch.device, info: DistInfo,
                 resume: bool, overwrite: bool, val_data) -> None:  # fmt: skip
        self.run, self.config, self.dev, self.info, self.val_data = run, config, dev, info, val_data
        solver = config.solver
        self.ckpt_path = run / CHECKPOINT_NAME
        state = load_checkpoint(self.ckpt_path) if resume else None
        if state is not None and "optimizer" not in state:
            raise CheckpointError(f"{self.ckpt_path}: no optimizer state to resume (an a3d-average "
                                  "checkpoint?); fine-tune it with --set solver.init=PATH")  # fmt: skip
        if solver.precision not in PRECISIONS:
            expected = " or ".join(PRECISIONS)
            raise ValueError(f"solver.precision={solver.precision!r}: expected {expected}")
        if solver.minutes < 0:
            raise ValueError(f"solver.minutes={solver.minutes}: expected > 0, or 0 for no time budget")
        if solver.init and solver.pretrained:
            raise ValueError("solver.init and solver.pretrained are both set: a run starts from one of them")
        if solver.freeze_depth and not (solver.init or state):
            raise ValueError(f"solver.freeze_depth={solver.freeze_depth} keeps the depth trunk's initial "
                             "weights: give them with solver.init")  # fmt: skip
        if solver.freeze_color and not (solver.init or solver.pretrained or state):
            raise ValueError(f"solver.freeze_color={solver.freeze_color} keeps the colour trunk's initial "
                             "weights: give them with solver.pretrained=FILE (a3d-vgg16-weights) or "
                             "solver.init")  # fmt: skip
        # A fine-tuned run keeps its checkpoint's regression targets (statistics, mean sizes), so the
        # head's deltas mean what they meant; a resumed run's own checkpoint supersedes it.
        start = state or (load_trained_state(solver.init) if solver.init else None)
        earlier = [run / name for name in (CHECKPOINT_NAME, METRICS_NAME, PLOT_NAME)]
        if state is None and any(path.exists() for path in earlier):
            if not overwrite:
                raise ValueError(f"{run}: a run exists here; pass --resume to continue it, --force to start "
                                 "it again, or pick another --out")  # fmt: skip
            if info.is_main:
                for path in earlier:
                    path.unlink(missing_ok=True)
            barrier(info)
        if info.is_main:
            run.mkdir(parents=True, exist_ok=True)
            self.write_config()
        self.start = int(state["iteration"]) if state else 0

        self.clock_start = time.monotonic()  # solver.minutes' clock (a3d.train.budget)
        self.budget = solver if solver.minutes > 0 else None  # the ceiling and its lr steps
        cache = Path(config.data.cache_dir) if config.data.cache_dir else run / "cache"
        if not info.is_main:
            barrier(info)  # rank 0 fills the proposal cache first
        mean_sizes = start["mean_sizes"].numpy() if start else None
        progress = info.is_main and config.log.progress
        self.roidb = build_roidb(data, config, cache, mean_sizes, progress=progress)
        if info.is_main:
            barrier(info)
        if start:
            self.stats = TargetStats.from_tensors(start["target_stats"])
        else:
            self.stats = compute_target_stats(self.roidb.records, config.data.flip)

        if solver.threads > 0:
            torch.set_num_threads(solver.threads)
        torch.manual_seed(solver.seed)
        model = A3DNet(config.net)
        if solver.pretrained and not state:
            loaded = load_vgg16_imagenet(model, solver.pretrained, trunks=solver.pretrained_trunks)
            if info.is_main:
                logger.info("solver.pretrained: %s", describe_loaded(model, loaded, solver.pretrained))
        elif solver.init and not state:
            load_weights(model, start["model"], solver.init)
        model.freeze_color(solver.freeze_color)
        model.freeze_depth(solver.freeze_depth)
        if solver.frozen_norms:
            model.freeze_norms()
        # channels-last convolutions: oneDNN's fast layout on CPUs (1.2x in fp32, and what AMX's bf16 wants)
        model.to(dev, memory_format=torch.channels_last)
        self.bf16 = solver.precision == "bf16"
        if self.bf16 and dev.type == "cpu" and not bf16_instructions() and info.is_main:
            logger.warning("solver.precision=bf16: this CPU has no native bfloat16 (AMX, AVX-512 BF16), "
                           "so PyTorch emulates it and training runs slower than fp32")  # fmt: skip
        groups = param_groups(model, solver.weight_decay, model.color_trunk, solver.color_lr_mult)
        self.optimizer = torch.optim.SGD(groups, lr=solver.lr, momentum=solver.momentum)
        if state:
            load_weights(model, state["model"], self.ckpt_path)
            self.optimizer.load_state_dict(state["optimizer"])
        self.net = wrap_model(model, info)
        features = ""
        if model.color_frozen and not config.data.augment:
            if not info.is_main:
                barrier(info)  # rank 0 computes the cache first
            features, computed = cache_color_features(
                self.roidb.records, model.color_trunk, config.data.input_scale, dev, self.bf16, progress
            )
            if info.is_main:
                logger.info("solver.freeze_color: the frozen colour trunk's features (%s) cached for %d of "
                            "%d frames", features, computed, len(self.roidb.records))  # fmt: skip
                barrier(info)

        self.metrics = MetricsLog(run / METRICS_NAME, self.start if state else None) if info.is_main else None
        if self.metrics:
            self.metrics.write({"kind": "data", "iter": self.start, "world_size": info.world_size,
                                **describe(self.roidb)})  # fmt: skip
            for line in self.roidb.skipped:
                logger.info("skipped %s", line)
            large = sum(max(r.image_size) > WORKING_SIDE for r in self.roidb.records)
            if large:
                logger.warning(
                    "%d of the %d training frames are larger than %d pixels across, which a3d-run brings "
                    "down to %d before the network sees them (docs/running.md \"Frames larger than 640 "
                    "across\"): train on frames of that size, or run the model with --working-side 0",
                    large, len(self.roidb.records), WORKING_SIDE, WORKING_SIDE,
                )
        dataset = BatchDataset(self.roidb.records, self.stats, config,
                               solver.iterations, info.rank, info.world_size, features)  # fmt: skip
        self.loader = batch_loader(dataset, self.start, config.data.workers, pin_memory=dev.type == "cuda")

    def loop(self) -> TrainResult:
        solver, log, info = self.config.solver, self.config.log, self.info
        bar = tqdm(total=solver.iterations, initial=self.start, unit="it", dynamic_ncols=True, desc="train",
                   disable=not (info.is_main and log.progress))  # fmt: skip
        postfix: dict[str, str] = {}
        window: dict[str, float] = {}
        window_n, window_start = 0, time.perf_counter()
        last_loss, val_map = None, None
        fit_at = self.start + PLAN_AFTER if self.budget else None
        if fit_at is not None and fit_at >= solver.iterations and info.is_main:
            logger.info("solver.minutes: the run's %d iterations are too few to time; it runs them all",
                        solver.iterations - self.start)  # fmt: skip
        warm_at, warm_start = self.start + WARMUP, 0.0
        # the run's length can change at each fit (solver.minutes), so it is read at every iteration
        count = itertools.count(self.start)
        iterations = itertools.takewhile(lambda i: i < self.config.solver.iterations, count)
        self.net.train()
        with _StopRequest(enabled=not info.enabled) as stop:
            for iteration, batch in zip(iterations, self.loader, strict=False):
                values = self.step(iteration, batch)
                done = iteration + 1
                if done == warm_at:
                    warm_start = time.perf_counter()
                if done == fit_at and done < solver.iterations:
                    solver = self.fit_to_budget(done, (done - warm_at) / (time.perf_counter() - warm_start))
                    bar.total = solver.iterations
                    fit_at += REFIT_EVERY
                final = done == solver.iterations
                for key, value in values.items():
                    window[key] = window.get(key, 0.0) + value
                window_n += 1
                postfix.update({short: f"{values[key]:.3f}" for short, key in _POSTFIX})
                if done % log.log_every == 0 or final:
                    means = mean_over_ranks({k: v / window_n for k, v in window.items()}, info, self.dev)
                    speed = window_n / (time.perf_counter() - window_start)
                    last_loss = means["loss"]
                    if self.metrics:
                        record = {"kind": "train", "iter": done, "lr": lr_at(iteration, solver), **means}
                        self.metrics.write({**record, "it_per_s": speed})
                    window, window_n, window_start = {}, 0, time.perf_counter()
                if self.val_data is not None and ((log.val_every and done % log.val_every == 0) or final):
                    if info.is_main:
                        val_map = self.validate(done)
                        postfix["val_map25"] = f"{100 * val_map:.1f}"
                    barrier(info)
                if done % log.checkpoint_every == 0 or final:
                    self.checkpoint(done)
                bar.set_postfix(postfix, refresh=False)
                bar.update(1)
                if stop.requested and not final:
                    if done % log.checkpoint_every:
                        self.checkpoint(done)
                    bar.close()
                    raise TrainingInterrupted(f"checkpoint of iteration {done} saved in {self.ckpt_path}; "
                                              f"--resume continues")  # fmt: skip
        bar.close()
        return TrainResult(self.run, max(self.start, solver.iterations), last_loss, val_map)

    def write_config(self) -> None:
        """config.json: the run's resolved configuration (with a time budget, its latest fit)."""
        atomic_write_bytes(self.run / CONFIG_NAME, (self.config.to_json() + "\n").encode())

    def fit_to_budget(self, done: int, rate: float) -> SolverConfig:
        """Fit the run's length to solver.minutes at ``rate`` (the ranks' mean), rewrite
        config.json with the fitted schedule and say it (a3d.train.budget)."""
        budget = self.budget
        left = budget.minutes * 60 - (time.monotonic() - self.clock_start) - END_SECONDS
        agreed = mean_over_ranks({"rate": rate, "left": left}, self.info, self.dev)
        fitted = fit_schedule(budget, done, agreed["rate"], agreed["left"], self.config.solver)
        self.config = replace(self.config, solver=fitted)
        if self.info.is_main:
            self.write_config()
            plan = {"minutes": budget.minutes, "it_per_s": agreed["rate"], "ceiling": budget.iterations,
                    "iterations": fitted.iterations, "lr_steps": list(fitted.lr_steps)}  # fmt: skip
            self.metrics.write({"kind": "plan", "iter": done, **plan})
            capped = " (the ceiling: the run ends early)" if fitted.iterations == budget.iterations else ""
            logger.info("solver.minutes=%g: %d iterations fit at %.2f it/s%s, lr steps %s",
                        budget.minutes, fitted.iterations, agreed["rate"], capped,
                        ", ".join(map(str, fitted.lr_steps)) or "none")  # fmt: skip
        return fitted

    def step(self, iteration: int, batch: dict) -> dict[str, float]:
        """One SGD step; returns the loss terms and the foreground count."""
        solver = self.config.solver
        for group in self.optimizer.param_groups:
            group["lr"] = lr_at(iteration, solver) * group.get("lr_mult", 1.0)
        torch.manual_seed(iteration_seed(solver.seed, iteration, self.info.rank))
        terms = forward_loss(self.net, _to_device(batch, self.dev), solver, self.bf16)
        if not torch.isfinite(terms.total):
            loss = float(terms.total.detach())
            raise FloatingPointError(f"iteration {iteration}: loss {loss} on {batch['frames']}; lower the lr")
        self.optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        self.optimizer.step()
        return {**terms.as_floats(), "fg": float((batch["labels"] > 0).sum())}

    def checkpoint(self, done: int) -> None:
        """Check the ranks agree, then (rank 0) write the checkpoint and the loss plot."""
        digests = check_in_sync(self.net, self.info)
        if not self.info.is_main:
            return
        save_checkpoint(self.ckpt_path, {
            "iteration": done,
            "config": self.config.to_json(),
            "model": {k: v.contiguous() for k, v in unwrap(self.net).state_dict().items()},  # row-major
            "optimizer": self.optimizer.state_dict(),
            "target_stats": self.stats.to_tensors(),
            "mean_sizes": torch.from_numpy(np.asarray(self.roidb.mean_sizes, np.float64)),
            "classes": list(CLASSES),
        })  # fmt: skip
        if self.info.enabled:
            self.metrics.write({"kind": "sync", "iter": done, "digests": digests})
        plot_losses(self.run / METRICS_NAME, self.run / PLOT_NAME)

    def validate(self, done: int) -> float:
        """mAP of the current weights on the validation frames (rank 0), logged as a "val" line."""
        t0 = time.perf_counter()
        model = unwrap(self.net)
        detector = TorchDetector.build(model, self.config, self.stats, self.roidb.mean_sizes, self.dev)
        result = validate(detector, self.val_data, self.config.log.val_frames)
        self.metrics.write({
            "kind": "val",
            "iter": done,
            "map25": result.map_all(0.25),
            "map25_present": result.map_present(0.25),
            "map50": result.map_all(0.5),
            "frames": result.num_frames,
            "seconds": time.perf_counter() - t0,
            "ap25": {c.name: c.ap[0.25] for c in result.classes if c.present},
        })  # fmt: skip
        return result.map_all(0.25)
