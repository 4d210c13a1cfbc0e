"""The live view opens, or says in one line why not: the viewer found where pip put it, no display
reported before any frame (exit 2, no traceback), and a viewer a3d starts listens on loopback only."""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

from a3d.runtime.viewer import launch
from a3d.runtime.viewer.options import add_viewer_args

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_viewer_args(parser)
    return parser.parse_args(list(argv))


def _executable(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "rerun"
    path.write_text("#!/bin/sh\n")
    path.chmod(0o755)
    return path


def test_viewer_found_on_path_then_next_to_python_then_in_rerun_cli(tmp_path: Path, monkeypatch) -> None:
    on_path = _executable(tmp_path / "path")
    beside = _executable(tmp_path / "venv" / "bin")
    python = str(tmp_path / "venv" / "bin" / "python")
    assert launch.find_viewer({"PATH": str(on_path.parent)}, python) == str(on_path)
    assert launch.find_viewer({"PATH": str(tmp_path / "empty")}, python) == str(beside)  # venv not activated
    packaged = launch.find_viewer({"PATH": ""}, str(tmp_path / "elsewhere" / "python"))
    assert packaged is not None and Path(packaged).parent.name == "rerun_cli"  # rerun-sdk's own binary
    monkeypatch.setattr(launch.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(launch.ViewerError, match=r"^rerun viewer not found on PATH, next to .*python"):
        launch.check_can_launch(_args(), {"PATH": "", "DISPLAY": ":0"}, str(tmp_path / "python"), "linux")


@pytest.mark.parametrize(
    ("environ", "platform", "shown"),
    [
        ({}, "linux", False),
        ({"DISPLAY": ""}, "linux", False),
        ({"DISPLAY": ":0"}, "linux", True),
        ({"WAYLAND_DISPLAY": "wayland-0"}, "linux", True),
        ({}, "darwin", True),
    ],
)
def test_display_detection(environ: dict, platform: str, shown: bool) -> None:
    assert launch.has_display(environ, platform) is shown


def test_which_flags_start_a_viewer() -> None:
    assert launch.launches_viewer(_args()) and launch.launches_viewer(_args("--serve"))
    for argv in (["--headless"], ["--save", "x.rrd"], ["--connect"], ["--stdout"]):
        assert not launch.launches_viewer(_args(*argv))


def test_no_display_is_one_line_before_any_frame_exit_2(tmp_path: Path) -> None:
    """The installed command, without DISPLAY/WAYLAND_DISPLAY and without --headless."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = tmp_path / "det.jsonl"
    cmd = [sys.executable, "-m", "a3d.runtime.cli.run", str(SAMPLES), "--output", str(out)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    [line] = done.stderr.splitlines()
    assert line.startswith("a3d-run: error: no display (DISPLAY and WAYLAND_DISPLAY are not set)")
    for alternative in ("--serve", "--save", "--connect"):
        assert alternative in line
    assert not out.exists()  # no frame was processed


def test_viewer_command_binds_loopback_unless_asked() -> None:
    cmd = launch.viewer_command("/x/rerun", _args())
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and "0.0.0.0" not in cmd
    served = launch.viewer_command("/x/rerun", _args("--serve"))
    assert served[served.index("--bind") + 1] == "127.0.0.1" and "--serve-web" in served
    wide = launch.viewer_command("/x/rerun", _args("--bind", "0.0.0.0"))
    assert wide[wide.index("--bind") + 1] == "0.0.0.0"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_served_viewer_listens_on_loopback_only(monkeypatch) -> None:
    """A real `rerun --serve-web` started by launch(): every socket it listens on is 127.0.0.1."""
    monkeypatch.setattr(launch, "GRPC_PORT", _free_port())
    monkeypatch.setattr(launch, "WEB_PORT", _free_port())
    started = launch.launch(_args("--serve"))
    try:
        assert started.web_url == (
            f"http://127.0.0.1:{launch.WEB_PORT}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{launch.GRPC_PORT}%2Fproxy"
        )
        root = psutil.Process(started.process.pid)
        listening = [
            c.laddr
            for p in (root, *root.children(recursive=True))
            for c in p.net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN
        ]
        assert {a.port for a in listening} >= {launch.GRPC_PORT, launch.WEB_PORT}
        assert {a.ip for a in listening} == {"127.0.0.1"}
    finally:
        started.stop()
    assert started.process.poll() is not None


def test_connect_to_no_viewer_is_one_line_before_any_frame() -> None:
    port = _free_port()  # nothing listens there
    with pytest.raises(
        launch.ViewerError, match=rf"^no rerun viewer listening at rerun\+http://127.0.0.1:{port}/"
    ):
        launch.check_connect_target(_args("--connect", "--url", f"rerun+http://127.0.0.1:{port}/proxy"))
    with socket.create_server(("127.0.0.1", 0)) as server:
        url = f"rerun+http://127.0.0.1:{server.getsockname()[1]}/proxy"
        launch.check_connect_target(_args("--connect", "--url", url))  # a listener: no error
