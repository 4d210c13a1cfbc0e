"""bench/browser_check.py: its DevTools WebSocket client and pixel judge (fast, always run), and the
real-browser check itself (opt-in: A3D_BROWSER_TEST=1 with Debian chromium installed, ~1.5 min)."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import psutil
import pytest

from a3d.runtime.structures.classes import CLASS_COLORS_RGB, class_index
from bench import browser_check as bc

REPO = Path(__file__).resolve().parents[1]
OPT_IN = os.environ.get("A3D_BROWSER_TEST") == "1"


# ----------------------------------------------------------------------------- WebSocket client


def _server_frame(opcode: int, payload: bytes, final: bool = True) -> bytes:
    """An unmasked server frame, written independently of the client's code."""
    n = len(payload)
    head = bytes([(0x80 if final else 0) | opcode])
    if n < 126:
        head += bytes([n])
    elif n < 1 << 16:
        head += bytes([126]) + struct.pack("!H", n)
    else:
        head += bytes([127]) + struct.pack("!Q", n)
    return head + payload


def _read_client_frame(conn: socket.socket) -> tuple[int, bytes]:
    def exactly(n: int) -> bytes:
        data = b""
        while len(data) < n:
            data += conn.recv(n - len(data))
        return data

    b0, b1 = exactly(2)
    assert b1 & 0x80, "client frames must be masked"
    n = b1 & 0x7F
    if n == 126:
        (n,) = struct.unpack("!H", exactly(2))
    elif n == 127:
        (n,) = struct.unpack("!Q", exactly(8))
    mask = exactly(4)
    masked = exactly(n)
    return b0 & 0x0F, bytes(b ^ mask[i % 4] for i, b in enumerate(masked))


def test_websocket_client_speaks_rfc6455() -> None:
    """Handshake key, masked frames out (7/16/64-bit lengths), fragmented and 64-bit-length frames
    in, a ping answered with its payload, and a frame split across a socket timeout."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    big = "x" * 70_000
    seen: dict[str, object] = {}

    def serve() -> None:
        conn, _ = listener.accept()
        with conn:
            request = b""
            while b"\r\n\r\n" not in request:
                request += conn.recv(4096)
            key = next(
                line.split(b":", 1)[1].strip()
                for line in request.split(b"\r\n")
                if line.lower().startswith(b"sec-websocket-key")
            )
            accept = base64.b64encode(hashlib.sha1(key + b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11").digest())
            conn.sendall(
                b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                b"Sec-WebSocket-Accept: " + accept + b"\r\n\r\n"
            )
            seen["texts"] = [_read_client_frame(conn) for _ in range(3)]
            conn.sendall(_server_frame(0x9, b"ping!"))  # answered before the next message
            conn.sendall(_server_frame(0x1, b"hello ", final=False) + _server_frame(0x0, b"world"))
            conn.sendall(_server_frame(0x1, big.encode()))
            seen["pong"] = _read_client_frame(conn)
            frame = _server_frame(0x1, b'{"id": 7}')
            conn.sendall(frame[:3])
            seen["split"] = threading.Event()
            seen["split"].wait(5)  # type: ignore[union-attr]
            conn.sendall(frame[3:])

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    ws = bc.WebSocket(f"ws://127.0.0.1:{port}/devtools/page/X", timeout_s=5)
    try:
        for text in ("short", "m" * 300, big):
            ws.send_text(text)
        assert ws.recv_text() == "hello world"
        assert ws.recv_text() == big
        ws.sock.settimeout(0.3)
        with pytest.raises(TimeoutError):
            ws.recv_text()  # only part of a frame has arrived
        seen["split"].set()  # type: ignore[union-attr]
        ws.sock.settimeout(5)
        assert ws.recv_text() == '{"id": 7}'
    finally:
        ws.close()
        thread.join(5)
        listener.close()
    assert seen["texts"] == [(0x1, b"short"), (0x1, b"m" * 300), (0x1, big.encode())]
    assert seen["pong"] == (0xA, b"ping!")


def test_websocket_refuses_a_socket_off_loopback() -> None:
    with pytest.raises(bc.SetupError, match="off loopback"):
        bc.WebSocket("ws://10.0.0.1:9222/devtools/page/X", timeout_s=1)


def test_viewer_url_points_at_loopback_with_webgl() -> None:
    printed = "http://127.0.0.1:19090?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A19876%2Fproxy"
    url = bc.viewer_url(printed, 19876)
    assert url == "http://127.0.0.1:19090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A19876%2Fproxy&renderer=webgl"


# ----------------------------------------------------------------------------- pixel judge


def _write(path: Path, rgb: np.ndarray) -> Path:
    cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    return path


def test_pixel_judge_tells_a_render_from_the_loader(tmp_path: Path) -> None:
    loader = np.full((200, 320, 3), (12, 16, 17), np.uint8)
    loader[:10] = (20, 20, 20)
    rng = np.random.default_rng(0)
    scene = rng.integers(40, 200, (200, 320, 3), dtype=np.uint8)
    chair = CLASS_COLORS_RGB[class_index("chair")]
    cv2.rectangle(scene, (20, 20), (120, 150), chair, 3)

    flat = bc.screenshot_stats(_write(tmp_path / "loader.png", loader))
    assert flat.dominant_fraction > 0.9 and flat.class_pixels == {}
    assert not flat.looks_rendered(["chair"]) and not flat.looks_rendered()

    stats = bc.screenshot_stats(_write(tmp_path / "scene.png", scene))
    assert stats.class_pixels["chair"] >= 2 * 3 * (100 + 130)  # the rectangle's outline
    assert stats.looks_rendered(["chair"])
    assert not stats.looks_rendered(["chair", "table"])  # no table-coloured box on screen


# ----------------------------------------------------------------------------- the real check (opt-in)


def _check(tmp_path: Path, *flags: str, timeout: float) -> tuple[bc.ScreenshotStats, list[str]]:
    """Run the script on a demo recording; its stats and the recording's classes. Also asserts the
    script left no rerun or chromium process behind."""
    recording = tmp_path / "demo.rrd"
    out = tmp_path / "shot.png"
    subprocess.run(
        [sys.executable, "-m", "bench.make_demo_recording", str(recording), "--seed", "1"],
        cwd=REPO,
        check=True,
        timeout=120,
    )
    run = subprocess.run(
        [sys.executable, "-m", "bench.browser_check", str(recording), "--out", str(out), *flags],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    left = [
        p.info["cmdline"]
        for p in psutil.process_iter(["cmdline"])
        if str(recording) in (p.info["cmdline"] or [])
    ]
    assert left == [], f"processes left running: {left}"
    return bc.screenshot_stats(out), bc.recording_classes(recording)


@pytest.mark.slow  # a headless browser
@pytest.mark.skipif(not (OPT_IN and bc.CHROMIUM.exists()), reason="opt-in: A3D_BROWSER_TEST=1 and chromium")
def test_web_viewer_in_chromium_shows_the_boxes(tmp_path: Path) -> None:
    stats, classes = _check(tmp_path, "--wait", "45", timeout=300)
    assert classes == ["box", "chair", "door", "table"]  # synth seed 1's ground truth
    assert stats.size == (bc.WINDOW[1], bc.WINDOW[0])
    assert stats.dominant_fraction < 0.9 and stats.distinct_colours > 500
    assert all(stats.class_pixels.get(name, 0) >= 500 for name in classes), stats.class_pixels


@pytest.mark.slow  # a headless viewer
@pytest.mark.skipif(
    not (OPT_IN and any(Path("/usr/share/vulkan/icd.d").glob("lvp_icd*.json"))),
    reason="opt-in: A3D_BROWSER_TEST=1 and mesa-vulkan-drivers",
)
def test_native_headless_viewer_shows_the_boxes(tmp_path: Path) -> None:
    stats, classes = _check(tmp_path, "--native", timeout=180)
    assert stats.dominant_fraction < 0.9 and stats.distinct_colours > 500
    assert all(stats.class_pixels.get(name, 0) >= 500 for name in classes), stats.class_pixels


@pytest.mark.slow  # a3d-run on the samples, then a headless browser
@pytest.mark.skipif(not (OPT_IN and bc.CHROMIUM.exists()), reason="opt-in: A3D_BROWSER_TEST=1 and chromium")
def test_a3d_run_serve_prints_a_loopback_url_that_chromium_opens(tmp_path: Path) -> None:
    out = tmp_path / "serve.png"
    run = subprocess.run(
        [sys.executable, "-m", "bench.browser_check", "--a3d-run", "samples", "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "a3d-run --serve printed http://127.0.0.1:9090/?url=" in run.stdout
    left = [
        p.info["cmdline"] for p in psutil.process_iter(["cmdline"]) if "--serve" in (p.info["cmdline"] or [])
    ]
    assert left == [], f"processes left running: {left}"
    stats = bc.screenshot_stats(out)
    assert stats.dominant_fraction < 0.9 and stats.distinct_colours > 500


def test_shown_classes_are_the_last_frames_above_the_view_threshold(tmp_path: Path) -> None:
    lines = [
        {"frame": "a", "detections": [{"class": "bed", "score": 0.9}]},
        {"frame": "b", "detections": [{"class": "chair", "score": 0.7}, {"class": "lamp", "score": 0.2},
                                      {"class": "chair", "score": 0.6}, {"class": "door", "score": 0.5}]},
    ]  # fmt: skip
    path = tmp_path / "det.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    assert bc.shown_classes(path) == ["chair", "door"]
    path.write_text("")
    with pytest.raises(bc.SetupError, match="wrote no detections"):
        bc.shown_classes(path)
