"""Batch inference on Ray Data: a3d-run's frames spread over the workers of a Ray cluster.

The driver opens the source, checks the model and lists the frames to do (a3d.runtime.scale.plan);
Ray Data hands blocks of them to a pool of actors (``map_batches`` with a callable class), each
one Detector on ``threads`` threads with its own copy of the source, which it reads by position.
Every block comes back to the driver as a3d-run's lines and one-line problems: the lines go to a
part file at once (a3d.runtime.scale.parts), the problems to ``on_problem``; at the end the parts
are merged into the output in source order. Ray is imported only here, and only when a run starts.

The source's files and the model must be readable at the same paths on every node (a shared file
system; relative paths resolve against the driver's working folder, which each worker enters).
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import os
import re
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2

from a3d.runtime.detector import Detector
from a3d.runtime.errors import InputError
from a3d.runtime.extras import Needs
from a3d.runtime.io.detections_io import format_line
from a3d.runtime.network.model import DetectorModel
from a3d.runtime.pipeline import PipelineConfig
from a3d.runtime.scale.parts import Parts
from a3d.runtime.scale.plan import Listing, check_independent, list_frames
from a3d.runtime.selection import completed_frames
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.registry import FrameSource, SourceOptions, open_source
from a3d.runtime.structures.frame import Frame

if TYPE_CHECKING:
    import pyarrow as pa

NEEDS = Needs("ray", ("ray", "pyarrow"))
BLOCK_FRAMES = 64  # the most frames of a block (one part file: what an interrupted run keeps)
BLOCKS_PER_WORKER = 4  # a small run still gives every worker several blocks
RETRIES = 2  # a worker that died (a lost node) is restarted and its block redone this many times
_ANSI = re.compile(r"\x1b\[[0-9;]*m")  # Ray colours the names in its messages
_RAISED = re.compile(r"^[A-Za-z_][\w.]*(?:Error|Exception): (.+)$")  # a traceback's last line


@dataclass(frozen=True)
class RayJob:
    """What every worker needs: the opened source (copied to each), the model file, the pipeline
    settings the driver checked, the threads of each worker's Detector, the driver's folder."""

    source: FrameSource
    model: Path
    config: PipelineConfig
    threads: int = 1
    cwd: str = field(default_factory=os.getcwd)


@dataclass
class RayRun:
    """What a run did: ``written`` frames, ``failed`` one-line problems, ``already`` frames done before."""

    written: int = 0
    failed: list[str] = field(default_factory=list)
    already: int = 0


class RayFailed(RuntimeError):
    """Ray stopped the run (a worker that could not start or died, the cluster gone), in one line."""

    @classmethod
    def of(cls, error: Exception) -> RayFailed:
        """What went wrong in one line: the worker's own exception where Ray wraps one (a task's
        ``cause``) or quotes its traceback (an actor that could not start), else Ray's first line."""
        cause = getattr(error, "cause", None)
        text = _ANSI.sub("", str(cause if isinstance(cause, Exception) else error))
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        raised = [m.group(1) for line in lines if (m := _RAISED.match(line))]
        return cls(f"Ray: {raised[-1] if raised else lines[0] if lines else type(error).__name__}")


class DetectBlock:
    """One Ray actor: a Detector on the job's threads, and the job's source read by position."""

    def __init__(self, job: RayJob) -> None:
        try:
            os.chdir(job.cwd)  # relative paths resolve as on the driver
        except OSError as e:
            raise InputError(f"{job.cwd}: the driver's folder is not on this node ({e.strerror or e}); "
                             "give absolute paths on a shared file system") from None  # fmt: skip
        cv2.setNumThreads(job.threads)
        self.detector = Detector(DetectorModel.load(job.model, threads=job.threads), job.config)
        self.frames = _Cursor(job.source)

    def __call__(self, block: pa.Table) -> pa.Table:
        import pyarrow as pa

        positions = block.column("position").to_pylist()
        names = block.column("name").to_pylist()
        loaders = [self.frames.at(p, n) for p, n in zip(positions, names, strict=True)]
        outcomes = list(self.detector.detect_frames(loaders, score_threshold=0))  # a3d-run's lines: all
        lines = ["" if o.detections is None else format_line(o.detections) for o in outcomes]
        return pa.table({"position": positions, "line": lines, "problem": [o.problem for o in outcomes]})


class _Cursor:
    """The source's frames by position for one worker: read forward through the source's own
    listing (loaders read nothing until loaded), restarted only when a block lies before the last
    one (Ray hands an actor its blocks mostly in order)."""

    def __init__(self, source: FrameSource) -> None:
        self.source = source
        self.frames: Iterator[FrameLoader] | None = None
        self.next = 0

    def at(self, position: int, name: str) -> FrameLoader:
        """The loader at ``position``; one that fails naming the frame if the source changed since
        the driver listed it (another frame there, or none)."""
        if self.frames is None or position < self.next:
            self.frames, self.next = iter(self.source), 0
        loader = next(itertools.islice(self.frames, position - self.next, None), None)
        self.next = position + 1
        if loader is None or loader.name != name:
            return FrameLoader(name, name, functools.partial(_changed, name, position))
        return loader


def _changed(name: str, position: int) -> Frame:
    raise InputError(f"{name}: the source changed since its frames were listed (frame {position} is "
                     "another one now, or missing); run again")  # fmt: skip


class RayRunner:
    """A run on Ray, set up on the driver: the output started (or resumed) and the frames listed;
    ``run`` then does them (a3d-run SOURCE --ray and ``ray_detect`` share it)."""

    def __init__(
        self,
        job: RayJob,
        output: str | os.PathLike,
        *,
        resume: bool = False,
        done: set[str] | None = None,
        shard: tuple[int, int] = (0, 1),
        limit: int | None = None,
    ) -> None:
        """``done``: with ``resume``, the frames the output holds where the caller has read them."""
        self.job = job
        self.parts = Parts(output)
        self.done = self.parts.start(resume)
        if resume:
            self.done |= completed_frames(self.parts.output) if done is None else done
        self.listing: Listing = list_frames(job.source, self.done, shard, limit)

    def run(
        self,
        *,
        workers: int | None = None,
        address: str | None = None,
        on_problem: Callable[[str], None] | None = None,
        on_frame: Callable[[bool], None] | None = None,
    ) -> RayRun:
        """Detect the listed frames on ``workers`` actors (default: the cluster's CPUs / threads)
        of the Ray at ``address`` (None: the initialised one, else a new local one); ``on_problem``
        hears each one-line problem, ``on_frame(failed)`` each frame. A run stopped by an error or
        Ctrl-C (RayFailed, KeyboardInterrupt) keeps its finished blocks for --resume; a finished one
        merges them into the output."""
        result = RayRun(already=len(self.done), failed=list(self.job.source.incomplete))
        report = on_problem or (lambda problem: None)
        for problem in result.failed:
            report(problem)
        try:
            for line, problem in self._frames(address, workers):
                if problem:
                    result.failed.append(problem)
                    report(problem)
                result.written += bool(line)
                if on_frame is not None:
                    on_frame(bool(problem))
        except Exception as e:
            if not type(e).__module__.startswith("ray."):
                raise
            raise RayFailed.of(e) from e
        self.parts.merge(self.listing.index)
        return result

    def _frames(self, address: str | None, workers: int | None) -> Iterator[tuple[str, str]]:
        """``_blocks`` on the Ray at ``address``, started only when there are frames to do."""
        if self.listing.positions:
            with _RaySession(address) as ray:
                yield from self._blocks(ray, workers)

    def _blocks(self, ray: Any, workers: int | None) -> Iterator[tuple[str, str]]:
        """(line or "", problem or "") of every listed frame, a block at a time, each
        block's lines written to its part file before its frames are reported."""
        import pyarrow as pa

        threads = self.job.threads
        cpus = int(ray.cluster_resources().get("CPU", 0))
        workers = workers or max(1, cpus // threads)
        if workers * threads > cpus:
            raise InputError(f"{workers} workers x {threads} threads need {workers * threads} CPUs "
                             f"and the Ray cluster has {cpus}")  # fmt: skip
        listing = self.listing
        size = max(1, min(BLOCK_FRAMES, math.ceil(len(listing) / (workers * BLOCKS_PER_WORKER))))
        blocks = [
            pa.table({"position": listing.positions[i : i + size], "name": listing.names[i : i + size]})
            for i in range(0, len(listing), size)
        ]
        with warnings.catch_warnings():  # Ray 2.60 names no other way to bound the retries (deprecated)
            warnings.filterwarnings("ignore", "`ray_remote_args` is deprecated")
            results = ray.data.from_arrow(blocks).map_batches(
                DetectBlock,
                fn_constructor_args=(self.job,),
                batch_size=size,
                batch_format="pyarrow",
                compute=ray.data.ActorPoolStrategy(size=workers),
                num_cpus=threads,
                max_restarts=RETRIES,  # Ray Data's default, forever, loops on a frame that kills its worker
                max_task_retries=RETRIES,
            )
        for table in results.iter_batches(batch_size=None, batch_format="pyarrow"):
            columns = ("position", "line", "problem")
            positions, lines, problems = (table.column(c).to_pylist() for c in columns)
            self.parts.write([(p, line) for p, line in zip(positions, lines, strict=True) if line])
            yield from zip(lines, problems, strict=True)


class _RaySession:
    """The Ray at ``address`` for one run: the initialised one as it is, else one started (a local
    one for None) and shut down after; Ray Data's progress bars and notices off (a3d-run has its own)."""

    def __init__(self, address: str | None) -> None:
        self.address = address
        self.started = False

    def __enter__(self) -> Any:
        import ray

        if ray.is_initialized() and self.address is not None:
            raise InputError(f"address={self.address!r}: Ray is initialised in this process already "
                             "(ray.init); leave address out to run on that one")  # fmt: skip
        if not ray.is_initialized():
            ray.init(address=self.address, include_dashboard=False, logging_level=logging.ERROR)
            self.started = True
        context = ray.data.DataContext.get_current()
        context.enable_progress_bars = False
        context.print_on_execution_start = False
        context.enable_auto_log_stats = False
        logging.getLogger("ray.data").setLevel(logging.ERROR)  # its notices: a3d-run reports the run
        return ray

    def __exit__(self, *exc: object) -> None:
        if self.started:
            import ray

            ray.shutdown()


def ray_detect(
    source: str | os.PathLike,
    model: str | os.PathLike,
    output: str | os.PathLike,
    *,
    resume: bool = False,
    workers: int | None = None,
    threads: int = 1,
    address: str | None = None,
    source_options: SourceOptions | None = None,
    kind: str | None = None,
    on_problem: Callable[[str], None] | None = None,
    **detector_options: Any,
) -> RayRun:
    """Detect the objects in every frame of ``source`` on Ray and write a3d-run's detections file
    ``output`` (the same lines, in source order), as ``a3d-run SOURCE --ray`` does.

    ``source`` is opened as ``open_source(source, source_options, kind)`` and must be a kind whose
    frames every worker can read (plan.INDEPENDENT_KINDS; InputError otherwise); ``model`` is
    checked here first (ModelError), ``detector_options`` are ``Detector.load``'s keywords. Each
    of ``workers`` actors runs one Detector on ``threads`` threads (default: the cluster's CPUs /
    ``threads``), on the Ray at ``address`` (None: the initialised Ray, else a new local one).
    ``resume`` skips the frames ``output`` (and an interrupted run's parts) already hold. A bad
    frame is one line in the result's ``failed`` (and to ``on_problem``), and the run goes on.
    """
    NEEDS.check("ray_detect")
    for name, value in (("threads", threads), ("workers", 1 if workers is None else workers)):
        if value < 1:
            raise InputError(f"{name}: must be at least 1, got {value}")
    check_independent(source, kind)
    frames = open_source(source, source_options, kind)
    detector = Detector.load(model, threads, **detector_options)
    job = RayJob(frames, Path(model), detector.config, threads)
    return RayRunner(job, output, resume=resume).run(workers=workers, address=address, on_problem=on_problem)
