"""How an error names an option the reader can give: a3d's command-line flag or the Python keyword.

Sources and the pipeline raise the same errors for a3d-run and for Python callers, and the advice
in them ("give the intrinsics with ...") must name what that reader can type. ``option(name)`` is
the Python form (``intrinsics=(fx, fy, cx, cy)``) unless a command runs: the shared command
skeleton (a3d.runtime.cli.common) switches to the flags with ``command_line()`` while it runs.
A process-wide switch, not a context variable, because frames are read on a background thread too.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

_PYTHON = {
    "intrinsics": "intrinsics=(fx, fy, cx, cy)",
    "intrinsics_or_preset": "intrinsics=(fx, fy, cx, cy) or a TUM preset, "
    "a3d.runtime.sources.overrides.INTRINSICS_PRESETS['fr1']",
    "depth_scale": "depth_scale=S (metres per unit)",
    "resize_depth": "resize_depth=True",
    "source_format": "open_source(..., kind=NAME)",
    "source_format_name": "kind",
    "depth_topic": "depth_topic=TOPIC",
    "pose_topic": "pose_topic=TOPIC",
    "proposals_precomputed": "Detector.load(..., proposals='precomputed')",
    "ray": "ray_detect",
}
_COMMAND_LINE = {
    "intrinsics": "--intrinsics fx,fy,cx,cy",
    "intrinsics_or_preset": "--intrinsics fx,fy,cx,cy or --intrinsics fr1|fr2|fr3",
    "depth_scale": "--depth-scale S",
    "resize_depth": "--resize-depth",
    "source_format": "--source-format NAME",
    "source_format_name": "--source-format",
    "depth_topic": "--depth-topic TOPIC",
    "pose_topic": "--pose-topic TOPIC",
    "proposals_precomputed": "--proposals precomputed",
    "ray": "--ray",
}
_words = _PYTHON


def option(name: str) -> str:
    """How the reader gives option ``name`` (a key of the tables above)."""
    return _words[name]


def keyword(name: str) -> str:
    """An option's bare name: ``depth_scale``, or on the command line ``--depth-scale``."""
    return name if _words is _PYTHON else "--" + name.replace("_", "-")


@contextlib.contextmanager
def command_line() -> Iterator[None]:
    """Name the command-line flags while a command runs (restored after)."""
    global _words
    before, _words = _words, _COMMAND_LINE
    try:
        yield
    finally:
        _words = before
