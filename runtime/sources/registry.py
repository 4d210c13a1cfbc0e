"""Which frame source a3d-run (and ``Detector.detect_frames``) opens for a SOURCE argument.

Each kind registers how to recognise its SOURCE (a folder's files, a file's extension, a
``scheme:`` prefix), how to open it and the options of its own. Recognition goes in registration
order and the first kind that claims SOURCE opens it; ``--source-format NAME`` (``kind=NAME``)
skips recognition. Readers that need an optional extra (rosbags, pyrealsense2) import it only
when opened. From Python::

    open_source("rgbd_dataset_freiburg1_desk")                       # every option at its default
    open_source("frames", intrinsics=(525.0, 525.0, 319.5, 239.5), depth_scale=0.0002)
    open_source("run.bag", depth_topic="/camera/aligned_depth_to_color/image_raw")
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields
from importlib import import_module
from pathlib import Path
from typing import Protocol

from a3d.runtime.errors import InputError
from a3d.runtime.sources.arrays import IntrinsicsLike, check_depth_scale, intrinsics_from
from a3d.runtime.sources.base import FrameLoader
from a3d.runtime.sources.wording import keyword, option


class FrameSource(Protocol):
    """Frames to load, in order; ``incomplete`` holds "PATH: reason" for inputs found unusable
    before any frame is read (reported by the run, which goes on with the rest). A source that
    reads integer depth says its unit in a ``depth_scale`` attribute (metres per unit), which
    ``--depth-scale`` replaces (a3d.runtime.sources.overrides); without one it has none to replace."""

    incomplete: list[str]

    def __iter__(self) -> Iterator[FrameLoader]: ...


@dataclass(frozen=True)
class SourceOptions:
    """What a user may tell any source. ``intrinsics`` (an ``Intrinsics``, (fx, fy, cx, cy) or a
    3x3 K, as ``Detector.detect`` takes them) / ``depth_scale`` (metres per depth unit) override
    what the source says, applied by ``open_source`` to every source's frames (readers need not);
    ``resize_depth`` lets depth of another size than the colour be resized to it (refused
    otherwise); ``with_proposals`` / ``with_truth`` ask for precomputed proposals and ground truth
    where the source has them; ``extra`` holds the options of one kind (bag topics, ...)."""

    intrinsics: IntrinsicsLike | None = None  # an Intrinsics once built
    depth_scale: float | None = None
    resize_depth: bool = False
    with_proposals: bool = True
    with_truth: bool = False
    extra: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # frozen: the checked forms are set once, here (ArrayError naming the field)
        if self.depth_scale is not None:
            object.__setattr__(self, "depth_scale", check_depth_scale(self.depth_scale))
        if self.intrinsics is not None:
            object.__setattr__(self, "intrinsics", intrinsics_from(self.intrinsics))


@dataclass(frozen=True)
class SourceKind:
    """One kind of source: ``claims(spec)`` says whether SOURCE looks like it; ``open`` opens it."""

    name: str
    claims: Callable[[str], bool]
    open: Callable[[str, SourceOptions], FrameSource]
    describe: str
    options: tuple[str, ...] = ()  # the keys of SourceOptions.extra this kind reads


_KINDS: dict[str, SourceKind] = {}


def register(kind: SourceKind) -> None:
    _KINDS[kind.name] = kind


def kinds() -> list[str]:
    return list(_KINDS)


def recognised(spec: str | os.PathLike) -> bool:
    """Whether a registered kind claims SOURCE (which need not be a file: ``realsense``)."""
    return claiming_kind(spec) is not None


def claiming_kind(spec: str | os.PathLike) -> str | None:
    """The name of the kind that opens SOURCE (the first that claims it), without opening it;
    None when no kind does."""
    text = os.fspath(spec)
    return next((kind.name for kind in _KINDS.values() if kind.claims(text)), None)


def open_source(
    spec: str | os.PathLike, options: SourceOptions | None = None, kind: str | None = None, **given: object
) -> FrameSource:
    """The source SOURCE names (InputError "SOURCE: ..." when nothing can open it), opened with
    ``options`` or with keywords: SourceOptions' fields and the kind's own options (a bag's
    ``depth_topic``), every one defaulted; an option the kind does not read is an error."""
    options = _options(options, given)
    text = os.fspath(spec)
    if kind is not None:
        if kind not in _KINDS:
            known = ", ".join(_KINDS)
            raise InputError(f"{option('source_format_name')}: unknown format {kind!r} (one of: {known})")
        return _open(_KINDS[kind], text, options)
    claimed = claiming_kind(text)
    if claimed is not None:
        return _open(_KINDS[claimed], text, options)
    if not Path(text).exists() and ":" not in text:
        raise InputError(f"{text}: no such file or folder")
    known = "; ".join(f"{k.name}: {k.describe}" for k in _KINDS.values())
    raise InputError(f"{text}: not a frame source a3d knows ({known}); {option('source_format')} forces one")


def _options(options: SourceOptions | None, given: dict[str, object]) -> SourceOptions:
    """``options``, or SourceOptions from keywords (those not its fields go to ``extra``)."""
    if options is not None and given:
        raise TypeError("open_source: pass a SourceOptions or keyword options, not both")
    if options is not None:
        return options
    names = {f.name for f in fields(SourceOptions)}
    own = {key: given.pop(key) for key in list(given) if key not in names}  # the kind's own options
    extra: dict[str, object] = {**dict(given.pop("extra", None) or {}), **own}  # type: ignore[call-overload]
    return SourceOptions(**given, extra=extra)  # type: ignore[arg-type]


def _open(kind: SourceKind, spec: str, options: SourceOptions) -> FrameSource:
    """``kind`` opens ``spec`` once its own options are known, with the overrides applied."""
    unknown = sorted(set(options.extra) - set(kind.options))
    if unknown:
        theirs = ", ".join(keyword(name) for name in kind.options) or "none"
        raise InputError(f"{keyword(unknown[0])}: not an option of {kind.name} sources (theirs: {theirs})")
    return _overridden(kind.open(spec, options), options)


def _overridden(source: FrameSource, options: SourceOptions) -> FrameSource:
    """The user's intrinsics and depth unit applied to every frame (a3d.runtime.sources.overrides)."""
    from a3d.runtime.sources.overrides import with_overrides

    return with_overrides(source, options.intrinsics, options.depth_scale)


def _claims_seven_scenes(spec: str) -> bool:
    from a3d.runtime.sources.seven_scenes import is_seven_scenes

    return is_seven_scenes(spec)


def _open_seven_scenes(spec: str, options: SourceOptions) -> FrameSource:
    from a3d.runtime.sources.seven_scenes import SevenScenesSource

    return SevenScenesSource(spec, options.intrinsics)


# Before "a3d": a 7-Scenes folder's frame-NNNNNN.color.png files would also look like a frame folder.
register(
    SourceKind(
        "7scenes",
        _claims_seven_scenes,
        _open_seven_scenes,
        "a posed 7-Scenes-style folder (camera-intrinsics.txt, frame-NNNNNN.color/depth.png, .pose.txt)",
    )
)


def _is_frame_folder(spec: str) -> bool:
    path = Path(spec)
    if not path.is_dir():
        return False
    return any(name.endswith((".color.png", ".color.jpg", ".color.jpeg")) for name in os.listdir(path))


def _open_folder(spec: str, options: SourceOptions) -> FrameSource:
    from a3d.runtime.sources.folder import FolderSource

    return FolderSource(spec, with_proposals=options.with_proposals, with_truth=options.with_truth)


register(
    SourceKind("a3d", _is_frame_folder, _open_folder, "a folder of NAME.color.png + NAME.depth.png frames")
)


def _claims_tum(spec: str) -> bool:
    from a3d.runtime.sources.tum import is_tum_sequence

    return is_tum_sequence(spec)


def _open_tum(spec: str, options: SourceOptions) -> FrameSource:
    from a3d.runtime.sources.trajectory import DEFAULT_MAX_GAP
    from a3d.runtime.sources.tum import DEFAULT_MAX_DIFFERENCE, TumSource

    max_difference = float(options.extra.get("max_difference", DEFAULT_MAX_DIFFERENCE))  # type: ignore[arg-type]
    max_gap = float(options.extra.get("max_pose_gap", DEFAULT_MAX_GAP))  # type: ignore[arg-type]
    return TumSource(spec, options.intrinsics, max_difference, options.resize_depth, max_gap)


register(
    SourceKind(
        "tum",
        _claims_tum,
        _open_tum,
        "a TUM RGB-D sequence folder (rgb.txt, depth.txt)",
        ("max_difference", "max_pose_gap"),
    )
)


def _claims_sunrgbd(spec: str) -> bool:
    from a3d.runtime.sources.sunrgbd import is_sunrgbd

    return is_sunrgbd(spec)


def _open_sunrgbd(spec: str, options: SourceOptions) -> FrameSource:
    from a3d.runtime.sources.sunrgbd import SunOptions, open_sunrgbd

    sun = SunOptions(
        depth=str(options.extra.get("depth", "raw")),
        classes=str(options.extra.get("classes", "nyu19")),
        with_truth=options.with_truth,
        resize_depth=options.resize_depth,
    )
    return open_sunrgbd(spec, sun)


register(
    SourceKind(
        "sunrgbd",
        _claims_sunrgbd,
        _open_sunrgbd,
        "SUN RGB-D: release frame folders (or a tree of them), or VoteNet's sunrgbd_trainval",
        ("depth", "classes"),
    )
)


def _in_module(module: str, name: str, describe: str, options: tuple[str, ...] = ()) -> SourceKind:
    """A kind whose ``claims`` and ``open_source`` live in ``a3d.runtime.sources.MODULE``, imported
    only when first asked (the module imports its optional extra only when a source is opened)."""

    def claims(spec: str) -> bool:
        return import_module(f"a3d.runtime.sources.{module}").claims(spec)

    def open_(spec: str, options: SourceOptions) -> FrameSource:
        return import_module(f"a3d.runtime.sources.{module}").open_source(spec, options)

    return SourceKind(name, claims, open_, describe, options)


register(
    _in_module(
        "bag",
        "bag",
        "a ROS 1 .bag, a ROS 2 bag folder or a RealSense SDK .bag recording (needs: pip install 'a3d[bag]')",
        ("color_topic", "depth_topic", "pose_topic", "max_pose_gap"),
    )
)
register(
    _in_module(
        "realsense",
        "realsense",
        "realsense, realsense:SERIAL or realsense:RECORDING for an Intel RealSense camera "
        "(needs: pip install 'a3d[realsense]')",
    )
)
