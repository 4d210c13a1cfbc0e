"""Starting the rerun viewer a3d-run logs to: found where pip put it, on loopback, or a clear no.

The SDK's own spawn looks for ``rerun`` on PATH only (a venv that is not activated has it in its
``bin/``, not on PATH), starts it listening on every interface (0.0.0.0:9876), and on a machine
without a display the viewer dies while the SDK retries its connection for ~25 s, then raises.
So a3d-run starts the viewer itself:

- the executable is looked up on PATH, then next to the running Python (a venv's ``bin/``), then
  in the ``rerun_cli`` package that rerun-sdk installs (the binary itself);
- it is started with ``--bind 127.0.0.1`` (``--bind ADDR`` to choose another interface) on the
  SDK's default port 9876 (an already running viewer on that port is used as it is, as the SDK
  does), and a3d-run waits until it accepts connections, or reports its exit in one line;
- with no display (Linux without DISPLAY or WAYLAND_DISPLAY) the native viewer is not started
  at all: one line names the alternatives (--serve, --save, --connect) before any frame;
- ``--connect`` checks that a viewer listens at the address before any frame;
- ``--serve`` starts ``rerun --serve-web`` (the web viewer over HTTP on port 9090 and the gRPC
  server on 9876, both on the bind address) and prints the URL to open in a browser.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from a3d.runtime.errors import InputError

LOOPBACK = "127.0.0.1"
GRPC_PORT = 9876  # the SDK's default, which `rerun --connect` and the viewer's own defaults assume
WEB_PORT = 9090
START_TIMEOUT_S = 20.0
ALTERNATIVES = "use --serve (web viewer in a browser), --save FILE.rrd, --connect [--url URL], or --headless"


class ViewerError(InputError):
    """The viewer a3d-run was asked to start cannot be started (one line, before any frame)."""


@dataclass
class Launched:
    """A viewer a3d-run started (or found running): the gRPC URL to log to, the page to open
    (``--serve`` only) and the process (None when an already running viewer was used)."""

    grpc_url: str
    web_url: str | None
    process: subprocess.Popen | None

    def stop(self) -> None:
        """End a served viewer (its whole process group); a spawned window is left to the user."""
        if self.process is not None and self.process.poll() is None:
            os.killpg(self.process.pid, 15)
            self.process.wait(timeout=10)


def add_bind_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bind",
        default=LOOPBACK,
        metavar="ADDR",
        help="address the spawned or served viewer listens on (default: %(default)s, this machine only)",
    )


def launches_viewer(args: argparse.Namespace) -> bool:
    """True when the flags ask a3d-run to start a viewer: the native window (no sink flag) or --serve."""
    other_sink = args.stdout or args.connect or args.save is not None
    return bool(args.serve) or not (args.headless or other_sink)


def find_viewer(environ: Mapping[str, str] = os.environ, python: str = sys.executable) -> str | None:
    """The rerun executable: on PATH, next to ``python``, or the rerun_cli package's binary."""
    found = shutil.which("rerun", path=environ.get("PATH", ""))
    if found:
        return found
    beside = Path(python).parent / "rerun"
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside)
    spec = importlib.util.find_spec("rerun_cli")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        binary = Path(folder) / "rerun"
        if binary.is_file() and os.access(binary, os.X_OK):
            return str(binary)
    return None


def has_display(environ: Mapping[str, str] = os.environ, platform: str = sys.platform) -> bool:
    """Whether a native window can open: on Linux only with an X11 or Wayland display."""
    return not platform.startswith("linux") or bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def viewer_command(executable: str, args: argparse.Namespace) -> list[str]:
    """The rerun command line for the flags: the native viewer, or ``--serve-web`` for --serve."""
    cmd = [executable, "--bind", args.bind, "--port", str(GRPC_PORT)]
    if args.serve:
        cmd += ["--serve-web", "--web-viewer-port", str(WEB_PORT)]
    return cmd


def check_can_launch(
    args: argparse.Namespace,
    environ: Mapping[str, str] = os.environ,
    python: str = sys.executable,
    platform: str = sys.platform,
) -> str:
    """The viewer executable to start; ViewerError (one line) when there is none or no display."""
    if not args.serve and not has_display(environ, platform):
        raise ViewerError(
            "no display (DISPLAY and WAYLAND_DISPLAY are not set): the viewer window cannot open; "
            + ALTERNATIVES
        )
    executable = find_viewer(environ, python)
    if executable is None:
        raise ViewerError(
            f"rerun viewer not found on PATH, next to {python} or in the rerun_cli package "
            "(pip install 'a3d[view]'); or use --save FILE.rrd or --headless"
        )
    return executable


def check_connect_target(args: argparse.Namespace) -> None:
    """--connect: ViewerError (one line, before any frame) when nothing listens at the viewer's
    address; the SDK would retry in the background and raise at the end of the run instead."""
    url = args.url or f"rerun+http://{LOOPBACK}:{GRPC_PORT}/proxy"
    parts = urllib.parse.urlsplit(url)
    try:
        host, port = parts.hostname or LOOPBACK, parts.port or GRPC_PORT
    except ValueError:
        raise ViewerError(
            f"--url {url}: not a viewer address like rerun+http://127.0.0.1:9876/proxy"
        ) from None
    if not _accepts(host, port):
        raise ViewerError(
            f"no rerun viewer listening at {url} (start one with `rerun`); "
            "or use --serve, --save FILE.rrd or --headless"
        )


def launch(args: argparse.Namespace) -> Launched:
    """Start the viewer the flags ask for (see the module docstring) and wait until it listens."""
    executable = check_can_launch(args)
    host = LOOPBACK if args.bind in ("0.0.0.0", "::", "") else args.bind
    grpc_url = f"rerun+http://{host}:{GRPC_PORT}/proxy"
    web_url = f"http://{host}:{WEB_PORT}/?url={urllib.parse.quote(grpc_url, safe='')}" if args.serve else None
    if not args.serve and _accepts(host, GRPC_PORT):
        return Launched(grpc_url, None, None)  # a viewer is already running there: log to it
    log = tempfile.NamedTemporaryFile(prefix="a3d_rerun_", suffix=".log", delete=False)
    env = {**os.environ, "RERUN_APP_ONLY": "true"}  # the SDK sets this too: no analytics prompt
    process = subprocess.Popen(
        viewer_command(executable, args),
        stdin=subprocess.DEVNULL,
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
        start_new_session=True,  # a spawned window outlives a3d-run; a served one is stopped as a group
    )
    deadline = time.monotonic() + START_TIMEOUT_S
    ports = (GRPC_PORT, WEB_PORT) if args.serve else (GRPC_PORT,)
    while not all(_accepts(host, port) for port in ports):
        if process.poll() is not None or time.monotonic() > deadline:
            what = (
                f"exited with status {process.returncode}" if process.poll() is not None else "did not start"
            )
            last = _last_line(Path(log.name))
            raise ViewerError(f"rerun viewer {what} ({last or 'no output'}, log {log.name}); {ALTERNATIVES}")
        time.sleep(0.1)
    return Launched(grpc_url, web_url, process)


def _accepts(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.2):
            return True
    except OSError:
        return False


def _last_line(path: Path) -> str:
    lines = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""
