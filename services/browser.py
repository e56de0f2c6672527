"""Headless Chromium driven over the Chrome DevTools Protocol (CDP), for screenshots.

Follows the DevTools protocol (https://chromedevtools.github.io/devtools-protocol/):
Chromium starts with ``--remote-debugging-port=0`` and writes the port it chose to
``DevToolsActivePort`` in its profile directory; the page target's websocket takes JSON
commands ``{"id", "method", "params"}`` and answers with the same ``id``. Only four
commands are used (``Page.navigate``, ``Runtime.evaluate``, ``Emulation.
setDeviceMetricsOverride``, ``Page.captureScreenshot``), over the ``websockets``
library's synchronous client; no browser download is needed (the system's chromium).

The Rerun viewer draws with WebGL or WebGPU in a canvas. Headless on a machine without a
GPU, Chromium renders it with SwiftShader (ANGLE on SwiftShader's Vulkan, WebGL 2),
which needs ``--use-angle=swiftshader --enable-unsafe-swiftshader``
(:data:`SOFTWARE_GL_FLAGS`); the viewer then reports "Software rasterizer" and runs
WebGL 2 through wgpu's GL backend. Measured on a 2-core x86-64 machine (Debian 12,
Chromium 150, rerun-sdk 0.41 web viewer) while other test runs kept its load at 4-13:

=======================================  ==========================================
step                                     wall time
=======================================  ==========================================
chromium start to its CDP websocket      1-2 s
viewer page to its canvas (wasm start)   15-50 s
viewer page to a TE recording drawn      32 s at load 4-7, 52-58 s at load 12-13
(2 MB, 1280 x 800)                       (``--js-flags=--no-wasm-tier-up``: same)
``Page.captureScreenshot``               0.5-1.5 s idle viewer, 7-40 s while the
                                         viewer takes in a recording
=======================================  ==========================================
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["BrowserUnavailable", "BrowserSettings", "HeadlessChromium", "find_chromium",
           "stop_group", "SOFTWARE_GL_FLAGS"]

#: Chromium flags that let WebGL run on the CPU (SwiftShader) when there is no GPU.
SOFTWARE_GL_FLAGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                     "--ignore-gpu-blocklist")

#: Executables tried in this order when ``SSMPC_CHROMIUM`` is not set.
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def stop_group(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """SIGTERM the process group ``proc`` leads (started with ``start_new_session``),
    SIGKILL it after ``timeout_s``."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            proc.wait(timeout_s)
            return
        except subprocess.TimeoutExpired:
            continue


class BrowserUnavailable(RuntimeError):
    """No Chromium to run, or it did not start (the reason is the message)."""


def find_chromium() -> str | None:
    """The Chromium executable: ``SSMPC_CHROMIUM`` if set, else the first of
    :data:`CHROMIUM_NAMES` on ``PATH``; None when there is none."""
    env = os.environ.get("SSMPC_CHROMIUM")
    if env:
        return env if shutil.which(env) else None
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass(frozen=True)
class BrowserSettings:
    """How the headless browser runs.

    Parameters
    ----------
    width, height : int
        Viewport in CSS pixels, 200-4000.
    start_timeout_s : float
        Longest wait for Chromium to open its DevTools port, s.
    command_timeout_s : float
        Longest wait for the answer to one CDP command, s.
    extra_flags : tuple of str
        Flags added to :data:`SOFTWARE_GL_FLAGS` and the headless ones.
    scale : float
        Device scale factor, 1-4: device pixels per CSS pixel, set at start
        (``--force-device-scale-factor``); the screenshot is ``width * scale`` x
        ``height * scale`` px, the page laid out as at ``width`` x ``height``, its text
        drawn ``scale`` times as finely. (The DevTools override of the factor instead,
        ``Emulation.setDeviceMetricsOverride(deviceScaleFactor=2)``, left the Rerun
        viewer's canvas at ``width`` x ``height`` px with its interface zoomed twice:
        the layout of a viewport half the size, upsampled.)
    """

    width: int = 1600
    height: int = 1000
    start_timeout_s: float = 20.0
    command_timeout_s: float = 60.0
    extra_flags: tuple[str, ...] = field(default=())
    scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if not isinstance(v, int) or not 200 <= v <= 4000:
                raise ValueError(f"{name}: {v!r} is not an integer in 200..4000 px")
        if not isinstance(self.scale, (int, float)) or not 1 <= self.scale <= 4:
            raise ValueError(f"scale: {self.scale!r} is not a device scale factor in 1..4")
        for name in ("start_timeout_s", "command_timeout_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0 s")
        object.__setattr__(self, "extra_flags", tuple(self.extra_flags))


class HeadlessChromium:
    """One headless Chromium with one page, driven over CDP; a context manager.

    Parameters
    ----------
    settings : BrowserSettings, optional
    executable : str, optional
        Default :func:`find_chromium`.

    Raises
    ------
    BrowserUnavailable
        No executable, or it exited or did not open its DevTools port in time.
    """

    def __init__(self, settings: BrowserSettings | None = None,
                 executable: str | None = None) -> None:
        from websockets.sync.client import connect

        self.settings = settings or BrowserSettings()
        exe = executable or find_chromium()
        if exe is None:
            raise BrowserUnavailable("no chromium on PATH (set SSMPC_CHROMIUM or install "
                                     "chromium)")
        self._profile = tempfile.mkdtemp(prefix="ssmpc-chromium-")
        s = self.settings
        cmd = [exe, "--headless", "--no-sandbox", "--no-first-run", "--no-default-browser-check",
               "--disable-extensions", "--mute-audio", f"--user-data-dir={self._profile}",
               "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
               f"--window-size={s.width},{s.height}",
               f"--force-device-scale-factor={s.scale:g}", *SOFTWARE_GL_FLAGS, *s.extra_flags,
               "about:blank"]
        self._log = open(Path(self._profile) / "chromium.log", "wb")  # noqa: SIM115
        try:
            # its own process group, so that close() ends its renderer and GPU processes too
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=self._log,
                                         start_new_session=True)
        except OSError as exc:
            self._cleanup()
            raise BrowserUnavailable(f"{exe}: {exc}") from exc
        self._next_id = 0
        self._stack = contextlib.ExitStack()
        try:
            port = self._devtools_port()
            ws_url = self._page_websocket(port)
            self.ws = self._stack.enter_context(
                connect(ws_url, max_size=None, open_timeout=s.start_timeout_s))
        except BaseException:
            self.close()
            raise
        self.set_viewport(s.width, s.height)

    def set_viewport(self, width: int, height: int) -> None:
        """Size the page's viewport, CSS px (its screenshots are ``width * scale`` x
        ``height * scale`` px at the browser's :attr:`BrowserSettings.scale`)."""
        BrowserSettings(width, height)  # validates
        # deviceScaleFactor 0: no override, the factor the browser was started with
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height,
                  deviceScaleFactor=0, mobile=False)

    def _devtools_port(self) -> int:
        path = Path(self._profile) / "DevToolsActivePort"
        t_end = time.monotonic() + self.settings.start_timeout_s
        while time.monotonic() < t_end:
            if self.proc.poll() is not None:
                raise BrowserUnavailable(f"chromium exited with {self.proc.returncode}: "
                                         f"{self.stderr_tail()}")
            try:
                lines = path.read_text().split()
            except OSError:
                lines = []
            if lines:
                return int(lines[0])
            time.sleep(0.05)
        raise BrowserUnavailable(f"chromium opened no DevTools port in "
                                 f"{self.settings.start_timeout_s:g} s")

    def _page_websocket(self, port: int) -> str:
        t_end = time.monotonic() + self.settings.start_timeout_s
        while True:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as r:
                targets = json.load(r)
            pages = [t for t in targets if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
            if time.monotonic() > t_end:
                raise BrowserUnavailable("chromium has no page target")
            time.sleep(0.05)

    def stderr_tail(self, n: int = 800) -> str:
        """The end of Chromium's own log (stderr), for error messages."""
        try:
            self._log.flush()
            return (Path(self._profile) / "chromium.log").read_bytes()[-n:].decode(
                errors="replace")
        except OSError:
            return ""

    def call(self, method: str, **params) -> dict:
        """Send one CDP command and return its ``result``; events in between are dropped.

        Raises
        ------
        RuntimeError
            The browser answered with an error.
        TimeoutError
            No answer within ``command_timeout_s``.
        """
        self._next_id += 1
        mid = self._next_id
        self.ws.send(json.dumps({"id": mid, "method": method, "params": params}))
        t_end = time.monotonic() + self.settings.command_timeout_s
        while True:
            left = t_end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"CDP {method}: no answer in "
                                   f"{self.settings.command_timeout_s:g} s")
            msg = json.loads(self.ws.recv(timeout=left))
            if msg.get("id") != mid:
                continue
            if "error" in msg:
                raise RuntimeError(f"CDP {method}: {msg['error'].get('message', msg['error'])}")
            return msg.get("result", {})

    def navigate(self, url: str) -> None:
        """Open ``url`` in the page (returns once navigation starts)."""
        res = self.call("Page.navigate", url=url)
        if res.get("errorText"):
            raise RuntimeError(f"navigate {url}: {res['errorText']}")

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-serialisable)."""
        res = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in res:
            raise RuntimeError(f"evaluate: {res['exceptionDetails'].get('text')}")
        return res.get("result", {}).get("value")

    def screenshot(self) -> bytes:
        """A PNG of the viewport (``width * scale`` x ``height * scale`` px)."""
        res = self.call("Page.captureScreenshot", format="png")
        return base64.b64decode(res["data"])

    def close(self) -> None:
        """Stop Chromium and remove its temporary profile."""
        stack = getattr(self, "_stack", None)
        if stack is not None:
            try:
                stack.close()  # the websocket
            except Exception:
                pass
        proc = getattr(self, "proc", None)
        if proc is not None:
            stop_group(proc)
        self._cleanup()

    def _cleanup(self) -> None:
        try:
            self._log.close()
        except AttributeError:
            pass
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> HeadlessChromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
