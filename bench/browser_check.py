"""Real-browser check: rerun's web viewer, served on 127.0.0.1, shows an a3d recording.

Starts ``rerun --serve-web`` on loopback, opens the viewer in headless Debian Chromium (WebGL on
SwiftShader: WebGPU there crashes), waits for it to load and render, and saves a screenshot taken
over the Chrome DevTools protocol (plain ``chromium --screenshot`` only catches the loader). The
screenshot is then judged by its pixels: a loader-only or blank page has almost one colour and none
of the class colours of the boxes. Opt-in, slow (~1 min), not part of the test suite.

    .venv/bin/python -m bench.browser_check RUN.rrd --out /tmp/a3d_screens/web.png [--wait 45]
    .venv/bin/python -m bench.browser_check RUN.rrd --out /tmp/a3d_screens/native.png --native
    .venv/bin/python -m bench.browser_check --a3d-run samples --out /tmp/a3d_screens/serve.png

``--a3d-run SOURCE`` checks the product's own route: ``a3d-run SOURCE --serve`` runs, prints the
URL of the web viewer it serves (on 127.0.0.1, checked), and Chromium opens exactly that URL; the
classes expected on screen are those of the last frame's detections at a3d-run's view threshold.

``--native`` is the faster second route: the native viewer headless on Mesa's lavapipe Vulkan
(``apt-get install -y mesa-vulkan-drivers``), ``rerun FILE --headless --screenshot-to``.
Nothing here talks to anything but 127.0.0.1: Chromium's host resolver maps every other name to
NOT FOUND and a dead proxy catches the rest (the viewer page asks for web fonts, GitHub's latest
release, rerun's examples manifest and tel.rerun.io; they are listed as blocked). The rerun server
and Chromium run in their own process groups, killed whole at the end.

Exit status: 0 the screenshot shows the recording, 1 it looks blank or loader-only, 2 a setup error.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import hashlib
import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from a3d.runtime.cli.run import VIEW_MIN_SCORE
from a3d.runtime.models import model_path
from a3d.runtime.structures.classes import CLASS_COLORS_RGB, CLASSES

RERUN = Path(sys.prefix) / "bin" / "rerun"
A3D_RUN = Path(sys.prefix) / "bin" / "a3d-run"
CHROMIUM = Path("/usr/bin/chromium")
LOOPBACK = "127.0.0.1"
WINDOW = (1600, 1000)
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--disable-quic",
    "--disable-extensions",
    "--disable-default-apps",
    "--no-default-browser-check",
    "--metrics-recording-only",
    f"--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE {LOOPBACK}",
    # A dead proxy for everything; Chromium bypasses proxies for loopback by itself.
    f"--proxy-server=http://{LOOPBACK}:9",
)
# Console lines worth reporting (the viewer logs its shader compiler at DEBUG level).
CONSOLE_PATTERN = re.compile(r"\b(WARN|ERROR|panicked)\b|^exception:|Error:")
# A pixel "has" a class colour when every channel is within this many levels of it.
COLOUR_TOLERANCE = 12


class SetupError(RuntimeError):
    """Something the check needs is missing or did not start; the message says what to do."""


# ----------------------------------------------------------------------------- processes


def free_port() -> int:
    """A TCP port free on loopback right now (the kernel's pick)."""
    with socket.socket() as s:
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


def wait_for_port(port: int, deadline: float, proc: subprocess.Popen, what: str) -> None:
    """Block until ``port`` accepts on loopback; SetupError if ``proc`` dies or time runs out."""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SetupError(f"{what} exited with status {proc.returncode} before listening on {port}")
        with contextlib.suppress(OSError), socket.create_connection((LOOPBACK, port), timeout=1):
            return
        time.sleep(0.2)
    raise SetupError(f"{what} did not listen on {LOOPBACK}:{port} in time")


@contextlib.contextmanager
def process_group(
    cmd: Sequence[str], log: Path, env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen]:
    """Run ``cmd`` in its own session and kill the whole group on exit (rerun's Python wrapper
    execs a separate binary, Chromium forks helpers: killing the first pid alone leaves them)."""
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            list(cmd),
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        )
    try:
        yield proc
    finally:
        kill_group(proc)


def kill_group(proc: subprocess.Popen, grace_s: float = 5.0) -> None:
    """SIGTERM the process group, SIGKILL what is left after ``grace_s``."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline and _group_alive(proc.pid):
            proc.poll()
            time.sleep(0.1)
        if not _group_alive(proc.pid):
            break
    proc.wait(timeout=grace_s)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def disable_analytics(rerun: Path) -> None:
    """rerun's first run otherwise prints an analytics prompt (and would phone home later)."""
    subprocess.run([str(rerun), "analytics", "disable"], capture_output=True, timeout=30, check=False)


def wait_for_log(log: Path, pattern: str, deadline: float, proc: subprocess.Popen) -> re.Match[str]:
    """First match of ``pattern`` in the process log; SetupError if it dies or time runs out."""
    while time.monotonic() < deadline:
        match = re.search(pattern, log.read_text(errors="replace"))
        if match:
            return match
        if proc.poll() is not None:
            raise SetupError(
                f"rerun exited with status {proc.returncode}: {log.read_text(errors='replace')[-800:]}"
            )
        time.sleep(0.2)
    raise SetupError(f"rerun printed no web-viewer address in time; log {log}")


def viewer_url(printed: str, grpc_port: int) -> str:
    """The address rerun printed, pointed at 127.0.0.1 (it prints ``localhost``), forced to WebGL."""
    parts = urllib.parse.urlsplit(printed)
    query = dict(urllib.parse.parse_qsl(parts.query))
    query["url"] = f"rerun+http://{LOOPBACK}:{grpc_port}/proxy"
    query["renderer"] = "webgl"
    netloc = parts.netloc.replace("localhost", LOOPBACK)
    return urllib.parse.urlunsplit(
        (parts.scheme, netloc, parts.path or "/", urllib.parse.urlencode(query), "")
    )


# ----------------------------------------------------------------------------- DevTools over a WebSocket


def xor_mask(payload: bytes, mask: bytes) -> bytes:
    """RFC 6455 masking (its own inverse): byte i XOR mask[i % 4]."""
    data = np.frombuffer(payload, np.uint8)
    return (data ^ np.resize(np.frombuffer(mask, np.uint8), data.size)).tobytes()


class WebSocket:
    """The few parts of RFC 6455 the DevTools protocol needs: client handshake, masked text frames
    out, unmasked (possibly fragmented, multi-megabyte) frames in, ping/pong and close."""

    GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"

    def __init__(self, url: str, timeout_s: float) -> None:
        parts = urllib.parse.urlsplit(url)
        if parts.hostname not in (LOOPBACK, "localhost"):
            raise SetupError(f"refusing a DevTools socket off loopback: {url}")
        self.sock = socket.create_connection((LOOPBACK, parts.port or 80), timeout=timeout_s)
        key = base64.b64encode(os.urandom(16))
        self.sock.sendall(
            f"GET {parts.path} HTTP/1.1\r\nHost: {LOOPBACK}:{parts.port}\r\n"
            "Upgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key.decode()}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise SetupError("DevTools closed the socket during the WebSocket handshake")
            head += chunk
        head, rest = head.split(b"\r\n\r\n", 1)
        self.pending = bytearray(rest)
        self.message = bytearray()  # a fragmented text message being put together
        accept = base64.b64encode(hashlib.sha1(key + self.GUID).digest())
        if not head.startswith(b"HTTP/1.1 101") or accept not in head:
            raise SetupError(f"DevTools refused the WebSocket upgrade: {head[:200]!r}")

    def _send_frame(self, opcode: int, payload: bytes) -> None:
        n = len(payload)
        if n < 126:
            header = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
        elif n < 1 << 16:
            header = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
        else:
            header = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
        mask = os.urandom(4)
        self.sock.sendall(header + mask + xor_mask(payload, mask))

    def send_text(self, text: str) -> None:
        self._send_frame(0x1, text.encode())

    def _parse_frame(self) -> tuple[int, bool, bytes] | None:
        """(opcode, final, payload) of the first whole frame in the buffer, consumed; None if incomplete.
        Nothing is consumed until a whole frame is there, so a socket timeout never splits a frame."""
        buf = self.pending
        if len(buf) < 2:
            return None
        n, pos = buf[1] & 0x7F, 2
        if n >= 126:
            size = 2 if n == 126 else 8
            if len(buf) < pos + size:
                return None
            n = int.from_bytes(buf[pos : pos + size], "big")
            pos += size
        mask = b""
        if buf[1] & 0x80:
            mask, pos = bytes(buf[pos : pos + 4]), pos + 4
        if len(buf) < pos + n:
            return None
        payload = bytes(buf[pos : pos + n])
        opcode, final = buf[0] & 0x0F, bool(buf[0] & 0x80)
        del buf[: pos + n]
        return opcode, final, xor_mask(payload, mask) if mask else payload

    def recv_text(self) -> str:
        """The next whole text message; pings are answered, a close frame raises ConnectionError.
        A socket timeout (TimeoutError) leaves the stream intact: call again to go on."""
        while True:
            frame = self._parse_frame()
            if frame is None:
                chunk = self.sock.recv(1 << 20)
                if not chunk:
                    raise ConnectionError("DevTools closed the WebSocket")
                self.pending += chunk
                continue
            opcode, final, payload = frame
            if opcode == 0x8:
                raise ConnectionError("DevTools closed the WebSocket")
            if opcode == 0x9:
                self._send_frame(0xA, payload)
            elif opcode in (0x0, 0x1):
                self.message += payload
                if final:
                    text, self.message = self.message.decode(), bytearray()
                    return text

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._send_frame(0x8, b"")
        self.sock.close()


class DevTools:
    """Synchronous DevTools calls on one page; events that arrive meanwhile are kept for the report."""

    def __init__(self, ws: WebSocket) -> None:
        self.ws = ws
        self.next_id = 0
        self.console: list[str] = []
        self.off_loopback: list[str] = []  # requests the page tried beyond 127.0.0.1 (all blocked)

    def call(self, method: str, timeout_s: float = 30.0, **params: object) -> dict:
        self.next_id += 1
        self.ws.send_text(json.dumps({"id": self.next_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            message = self._receive(deadline)
            if message is not None and message.get("id") == self.next_id:
                if "error" in message:
                    raise SetupError(f"DevTools {method} failed: {message['error']}")
                return message.get("result", {})
        raise SetupError(f"DevTools {method} got no answer in {timeout_s:.0f} s")

    def idle(self, seconds: float) -> None:
        """Let the page run for ``seconds``, reading (and keeping) the events it sends."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self._receive(deadline)

    def _receive(self, deadline: float) -> dict | None:
        self.ws.sock.settimeout(max(0.05, min(1.0, deadline - time.monotonic())))
        try:
            message = json.loads(self.ws.recv_text())
        except TimeoutError:
            return None
        if message.get("method") == "Runtime.consoleAPICalled":
            args = message["params"].get("args", [])
            line = " ".join(str(a.get("value", a.get("description", ""))) for a in args)
            if CONSOLE_PATTERN.search(line):
                self.console.append(line)
        elif message.get("method") == "Runtime.exceptionThrown":
            self.console.append("exception: " + message["params"]["exceptionDetails"].get("text", ""))
        elif message.get("method") == "Network.requestWillBeSent":
            url = message["params"]["request"]["url"]
            if urllib.parse.urlsplit(url).hostname not in (LOOPBACK, None):
                self.off_loopback.append(url)
        return message


def devtools_json(port: int, path: str, timeout_s: float = 5.0) -> object:
    with urllib.request.urlopen(f"http://{LOOPBACK}:{port}{path}", timeout=timeout_s) as response:
        return json.loads(response.read())


def page_socket_url(port: int, deadline: float) -> str:
    """The DevTools WebSocket of Chromium's first page target (it opens about:blank)."""
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError):
            pages = [t for t in devtools_json(port, "/json/list") if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
        time.sleep(0.3)
    raise SetupError(f"Chromium's DevTools on {LOOPBACK}:{port} listed no page in time")


# ----------------------------------------------------------------------------- the two routes


def browser_screenshot(
    recording: Path, out: Path, *, port: int, web_port: int, wait_s: float, chromium: Path
) -> str:
    """Serve ``recording``, let Chromium render the web viewer for ``wait_s``, save a PNG; return the URL."""
    disable_analytics(RERUN)
    with tempfile.TemporaryDirectory(prefix="a3d_browser_") as tmp:
        tmp_dir = Path(tmp)
        server_log = tmp_dir / "rerun.log"
        serve = [str(RERUN), "--serve-web", "--bind", LOOPBACK, "--port", str(port)]
        serve += ["--web-viewer-port", str(web_port), str(recording)]
        with process_group(serve, server_log) as server:
            deadline = time.monotonic() + 60
            printed = wait_for_log(server_log, r"connect at (http://\S+)", deadline, server).group(1)
            wait_for_port(web_port, deadline, server, "rerun's web viewer")
            url = viewer_url(printed, port)
            chromium_screenshot(url, out, wait_s=wait_s, chromium=chromium, tmp_dir=tmp_dir)
    return url


def a3d_run_screenshot(
    source: Path, model: Path, out: Path, *, wait_s: float, chromium: Path, timeout_s: float
) -> tuple[str, list[str]]:
    """``a3d-run SOURCE --serve``: the URL it prints, opened in Chromium once the run is done and
    serving; returns the URL and the classes of the last frame's detections the view shows."""
    disable_analytics(RERUN)
    with tempfile.TemporaryDirectory(prefix="a3d_serve_") as tmp:
        tmp_dir = Path(tmp)
        detections, log = tmp_dir / "detections.jsonl", tmp_dir / "a3d-run.log"
        run = [str(A3D_RUN), str(source), "--model", str(model), "--serve"]
        run += ["--output", str(detections)]
        with process_group(run, log) as served:
            deadline = time.monotonic() + timeout_s
            url = wait_for_log(log, r"serving the recording at (http://\S+);", deadline, served).group(1)
            host = urllib.parse.urlsplit(url).hostname
            if host != LOOPBACK:
                raise SetupError(f"a3d-run --serve printed {url}: not on {LOOPBACK}")
            chromium_screenshot(url, out, wait_s=wait_s, chromium=chromium, tmp_dir=tmp_dir)
        return url, shown_classes(detections)


def shown_classes(detections: Path, min_score: float = VIEW_MIN_SCORE) -> list[str]:
    """Class names of the last frame's detections that a3d-run's view shows (score >= its default
    --view-min-score): the viewer opens at the end of the timeline."""
    lines = detections.read_text().splitlines()
    if not lines:
        raise SetupError(f"{detections}: a3d-run wrote no detections")
    last = json.loads(lines[-1])
    return sorted({d["class"] for d in last["detections"] if d["score"] >= min_score})


def chromium_screenshot(url: str, out: Path, *, wait_s: float, chromium: Path, tmp_dir: Path) -> None:
    """Open ``url`` in headless Chromium, let it render for ``wait_s`` and save a PNG of the page."""
    if not chromium.exists():
        raise SetupError(f"{chromium} missing: run `apt-get update && apt-get install -y chromium` (as root)")
    devtools_port = free_port()
    browser = [str(chromium), *CHROMIUM_FLAGS, f"--user-data-dir={tmp_dir / 'profile'}"]
    browser += [f"--remote-debugging-port={devtools_port}", f"--window-size={WINDOW[0]},{WINDOW[1]}"]
    with process_group([*browser, "about:blank"], tmp_dir / "chromium.log") as chrome:
        wait_for_port(devtools_port, time.monotonic() + 60, chrome, "Chromium's DevTools")
        ws = WebSocket(page_socket_url(devtools_port, time.monotonic() + 30), timeout_s=10)
        try:
            tools = DevTools(ws)
            tools.call("Runtime.enable")
            tools.call("Page.enable")
            tools.call("Network.enable")
            tools.call(
                "Emulation.setDeviceMetricsOverride",
                width=WINDOW[0],
                height=WINDOW[1],
                deviceScaleFactor=1,
                mobile=False,
            )
            tools.call("Page.navigate", url=url)
            tools.idle(wait_s)
            shot = tools.call("Page.captureScreenshot", timeout_s=60, format="png")
        finally:
            ws.close()
        for line in tools.console[-10:]:
            print(f"  console: {line.strip().splitlines()[0][:200]}")
        for blocked in sorted(set(tools.off_loopback)):
            print(f"  blocked off-loopback request: {blocked[:200]}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(shot["data"]))


def native_screenshot(recording: Path, out: Path, *, timeout_s: float) -> None:
    """The native viewer, headless on lavapipe Vulkan, writes the screenshot itself and quits."""
    if not any(Path("/usr/share/vulkan/icd.d").glob("lvp_icd*.json")):
        raise SetupError(
            "no lavapipe Vulkan driver: run `apt-get update && apt-get install -y mesa-vulkan-drivers`"
        )
    disable_analytics(RERUN)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    env = {**os.environ, "WGPU_BACKEND": "vulkan"}
    # Its gRPC server would listen on 0.0.0.0:9876 by default (and hand the file to a viewer already there).
    cmd = [str(RERUN), str(recording), "--headless", "--bind", LOOPBACK, "--port", str(free_port())]
    cmd += ["--screenshot-to", str(out), "--window-size", "1280x800"]
    with tempfile.TemporaryDirectory(prefix="a3d_native_") as tmp:
        log = Path(tmp) / "rerun.log"
        with process_group(cmd, log, env=env) as viewer:
            try:
                viewer.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired as err:
                tail = log.read_text(errors="replace")[-800:]
                raise SetupError(f"native viewer wrote no screenshot in {timeout_s:.0f} s: {tail}") from err
        if not out.exists():
            raise SetupError(
                f"native viewer exited {viewer.returncode} without a screenshot: {log.read_text()[-800:]}"
            )


# ----------------------------------------------------------------------------- judging the pixels


@dataclass(frozen=True)
class ScreenshotStats:
    """What the pixels say: a loader or blank page is one flat colour with no class colours."""

    size: tuple[int, int]  # (H, W)
    dominant_fraction: float  # share of pixels in the most common (quantised) colour
    distinct_colours: int  # distinct colours after quantising each channel to 32 levels
    class_pixels: dict[str, int]  # class name -> pixels within COLOUR_TOLERANCE of its colour

    def looks_rendered(self, expected: Sequence[str] = (), min_class_px: int = 50) -> bool:
        """Varied pixels, and every expected class colour (or any, with none expected) on screen."""
        varied = self.dominant_fraction < 0.9 and self.distinct_colours > 100
        if expected:
            coloured = all(self.class_pixels.get(name, 0) >= min_class_px for name in expected)
        else:
            coloured = any(n >= min_class_px for n in self.class_pixels.values())
        return varied and coloured


def screenshot_stats(png: Path) -> ScreenshotStats:
    bgr = cv2.imread(str(png), cv2.IMREAD_COLOR)
    if bgr is None:
        raise SetupError(f"{png}: not a readable image")
    rgb = bgr[..., ::-1].reshape(-1, 3).astype(np.int16)
    quantised = (rgb // 8) @ np.array([1024, 32, 1])
    counts = np.bincount(quantised)
    colours = np.asarray(CLASS_COLORS_RGB, dtype=np.int16)
    near = np.abs(rgb[:, None, :] - colours[None, :, :]).max(axis=2) <= COLOUR_TOLERANCE
    per_class = near.sum(axis=0)
    return ScreenshotStats(
        size=bgr.shape[:2],
        dominant_fraction=float(counts.max() / len(quantised)),
        distinct_colours=int((counts > 0).sum()),
        class_pixels={name: int(n) for name, n in zip(CLASSES, per_class, strict=True) if n},
    )


def recording_classes(recording: Path) -> list[str]:
    """Class names of the detections on screen: those logged at the recording's last frame (the
    viewer opens at the end of the timeline), from the boxes' class ids."""
    import rerun.chunk as rc

    by_frame: dict[int, set[str]] = {}
    for chunk in rc.RrdReader(str(recording)).stream():
        batch = chunk.to_record_batch()
        if batch.schema.metadata.get(b"rerun:entity_path", b"").decode() != "/world/detections":
            continue
        if "Boxes3D:class_ids" in batch.schema.names and "frame" in batch.schema.names:
            frames = batch.column("frame").to_pylist()
            for frame, ids in zip(frames, batch.column("Boxes3D:class_ids").to_pylist(), strict=True):
                by_frame.setdefault(frame, set()).update(CLASSES[i - 1] for i in ids or [])
    return sorted(by_frame[max(by_frame)]) if by_frame else []


# ----------------------------------------------------------------------------- CLI


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "recording",
        type=Path,
        nargs="?",
        help="an .rrd from a3d-run --save (or bench/make_demo_recording.py); not with --a3d-run",
    )
    parser.add_argument("--out", type=Path, required=True, help="the screenshot PNG to write")
    parser.add_argument(
        "--a3d-run",
        type=Path,
        metavar="SOURCE",
        help="run `a3d-run SOURCE --serve` and open the URL it prints (instead of serving a recording)",
    )
    parser.add_argument("--model", type=Path, default=model_path("live"), help="--a3d-run's model")
    parser.add_argument("--port", type=int, default=0, help="rerun's gRPC port (0: a free one)")
    parser.add_argument(
        "--web-viewer-port", type=int, default=0, help="the web viewer's HTTP port (0: a free one)"
    )
    parser.add_argument(
        "--wait", type=float, default=45.0, help="seconds the page renders before the screenshot"
    )
    parser.add_argument("--native", action="store_true", help="native headless viewer on lavapipe instead")
    parser.add_argument(
        "--timeout", type=float, default=120.0, help="--native, --a3d-run: seconds before giving up"
    )
    parser.add_argument("--chromium", type=Path, default=CHROMIUM)
    args = parser.parse_args(argv)
    if (args.recording is None) == (args.a3d_run is None):
        parser.error("give either a recording or --a3d-run SOURCE")
    if args.recording is not None and not args.recording.is_file():
        print(f"{args.recording}: no such file", file=sys.stderr)
        return 2
    started = time.monotonic()
    try:
        if args.a3d_run is not None:
            url, expected = a3d_run_screenshot(
                args.a3d_run, args.model, args.out, wait_s=args.wait, chromium=args.chromium,
                timeout_s=args.timeout,
            )  # fmt: skip
            print(f"a3d-run --serve printed {url} -> {args.out}")
        elif args.native:
            native_screenshot(args.recording, args.out, timeout_s=args.timeout)
            print(f"native viewer -> {args.out}")
        else:
            port = args.port or free_port()
            web_port = args.web_viewer_port or free_port()
            url = browser_screenshot(
                args.recording, args.out, port=port, web_port=web_port, wait_s=args.wait,
                chromium=args.chromium,
            )  # fmt: skip
            print(f"{url} -> {args.out}")
    except (SetupError, subprocess.TimeoutExpired, OSError) as err:
        print(f"browser_check: {err}", file=sys.stderr)
        return 2
    if args.a3d_run is None:
        expected = recording_classes(args.recording)
    stats = screenshot_stats(args.out)
    ok = stats.looks_rendered(expected)
    print(
        f"{'OK' if ok else 'BLANK?'} in {time.monotonic() - started:.0f} s: {stats.size[1]}x{stats.size[0]}, "
        f"dominant colour {stats.dominant_fraction:.0%}, {stats.distinct_colours} colours; "
        f"class-colour pixels {stats.class_pixels}; expected classes {expected}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
