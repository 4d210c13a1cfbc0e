"""What the rerun view is asked for, without importing rerun (an optional extra, ``a3d[view]``).

The flags are the rerun SDK's standard script flags (``rr.script_add_args``), declared here so
that ``a3d-run --headless`` and the Python API run on a device without rerun installed; the
view itself (a3d.runtime.viewer.view) is imported only when a recording is asked for, and its
absence is then one line naming the extra.
"""

from __future__ import annotations

import argparse
import importlib
from types import ModuleType

from a3d.runtime.errors import InputError
from a3d.runtime.extras import Needs, installed
from a3d.runtime.viewer.launch import add_bind_arg
from a3d.runtime.viewer.shapes import ViewOptions

__all__ = ["ViewOptions", "add_viewer_args", "check_installed", "load_view", "viewer_requested"]


def add_viewer_args(parser: argparse.ArgumentParser) -> None:
    """The rerun SDK's script flags (the names and meaning of ``rr.script_add_args``), and --bind
    for the viewer a3d-run starts (a3d.runtime.viewer.launch)."""
    parser.add_argument("--headless", action="store_true", help="no viewer window (alone: nothing is logged)")
    parser.add_argument("--connect", action="store_true", help="send to a running rerun viewer (see --url)")
    parser.add_argument("--serve", action="store_true", help="serve the web viewer and open it in a browser")
    parser.add_argument("--url", help="the viewer to --connect to (default: rerun's local viewer)")
    parser.add_argument(
        "--save", metavar="FILE.rrd", help="record to this .rrd file (open it with: rerun FILE.rrd)"
    )
    parser.add_argument(
        "--stdout", action="store_true", help="write the recording to stdout, for a pipe into rerun"
    )
    add_bind_arg(parser)


def viewer_requested(args: argparse.Namespace) -> bool:
    """False for --headless with no sink: then nothing is logged (and nothing buffered in memory)."""
    return not args.headless or bool(args.save or args.connect or args.serve or args.stdout)


NOT_INSTALLED = (
    "rerun is not installed: the view and --save need it (pip install 'a3d[view]'); "
    "--headless alone runs without it"
)


def check_installed(args: argparse.Namespace) -> None:
    """InputError naming the extra when the flags ask for a view or recording and rerun is missing,
    before any other viewer check could suggest a mode (--serve, --save) that needs it too."""
    if viewer_requested(args) and not installed("rerun"):
        raise InputError(NOT_INSTALLED)


def load_view(caller: str = "") -> ModuleType:
    """a3d.runtime.viewer.view, or InputError saying how to install rerun: for a3d-run (or to run
    headless), or, with ``caller`` (a Python method), MissingExtra naming it and the extra."""
    if caller:
        Needs("view", ("rerun",)).check(caller)
    try:
        return importlib.import_module("a3d.runtime.viewer.view")
    except ModuleNotFoundError as e:
        if not (e.name or "").startswith("rerun"):
            raise
        raise InputError(NOT_INSTALLED) from None
