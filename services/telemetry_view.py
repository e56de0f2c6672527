"""The trend display in a browser: serve an ``.rrd`` with Rerun's web viewer, screenshot it.

What an operator does on a headless machine (README, "Telemetry"), automated:
``rerun --serve-web`` (the viewer binary of the rerun-sdk) serves a compacted copy of
the recording (``rerun rrd optimize``) and the viewer's wasm on loopback; headless
Chromium (:mod:`services.browser`, software WebGL) opens the viewer at
``?url=rerun+http://127.0.0.1:<grpc>/proxy``; the screenshot is taken once the viewer
has drawn the recording and two frames :attr:`ViewSettings.settle_s` apart are alike.

The viewer draws everything (panel titles, legends, lines) into one canvas; its DOM holds
the canvas and a loading/crash message, and its accessibility tree only the page title.
So "drawn" is judged from pixels (:func:`coloured_fraction`): the viewer's own interface
is grey, the series are coloured; the canvas must be shown as well. Measured
(rerun-sdk 0.41, Chromium 150 with software WebGL):

==================================================  ===============
screen                                              coloured pixels
==================================================  ===============
page before the wasm starts                         0.0 %
"Loading Application Bundle", canvas not shown      0.0-0.3 %
TE 0 -> 2 recording drawn (1600 x 1000, dark)       2.1 %
3-CV test recording drawn (1000 x 700, dark)        0.9 %
==================================================  ===============

The panels are found by name with OCR (:func:`check_titles`, :mod:`services.screen_text`):
:func:`panel_layout` walks the blueprint's containers and shares to the part of the
screen each view gets, and each view's title must be read in that panel's title bar.
The viewer's own bars and a title's place in its bar are measured constants (rerun-sdk
0.41): the top bar 36 CSS px, the collapsed time panel 29, a title's centre 14-16 px
below its panel's top edge and its start 28-29 px right of its left edge. In 12
screenshots of 5 TE recordings at 1280 x 800 (device scale 1, read enlarged x2) and one
at 1600 x 1000, every one of the 11 titles was read in its own title bar; at device
scale 2 too (8 renders of one recording). A title in another panel's bar, only in a
legend lower down, or absent is reported as such.
"""

from __future__ import annotations

import io
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.browser import BrowserSettings, HeadlessChromium, stop_group

__all__ = ["NotDrawn", "ViewSettings", "ServedRecording", "viewer_url", "coloured_fraction",
           "screenshot_recording", "decode_png", "Panel", "panel_layout", "panel_boxes",
           "TitleCheck", "check_titles"]

class NotDrawn(TimeoutError):
    """The viewer did not draw the recording in time; ``png`` is the last screenshot
    (None if none was taken)."""

    def __init__(self, message: str, png: bytes | None) -> None:
        super().__init__(message)
        self.png = png


#: Saturation (max - min of R, G, B over 255) above which a pixel counts as coloured.
COLOUR_SATURATION = 0.25


@dataclass(frozen=True)
class ViewSettings:
    """How the recording is shown and when the screenshot is taken.

    Parameters
    ----------
    width, height : int
        Browser viewport, CSS px.
    theme : str
        ``"dark"`` (the viewer's default) or ``"light"``.
    timeout_s : float
        Longest wait for the viewer to draw the recording, s.
    settle_s : float
        Two screenshots this far apart must be alike, s.
    min_coloured : float
        Fraction of coloured pixels (:func:`coloured_fraction`) that counts as drawn.
    scale : float
        Device scale factor (:class:`services.browser.BrowserSettings`): the screenshot
        is ``width * scale`` x ``height * scale`` px.
    """

    width: int = 1600
    height: int = 1000
    theme: str = "dark"
    timeout_s: float = 240.0
    settle_s: float = 1.5
    min_coloured: float = 0.002
    scale: float = 1.0

    def __post_init__(self) -> None:
        BrowserSettings(self.width, self.height, scale=self.scale)  # validates the size
        if self.theme not in ("dark", "light"):
            raise ValueError(f"theme: {self.theme!r} is not 'dark' or 'light'")
        if not self.timeout_s > 0 or not self.settle_s > 0:
            raise ValueError("timeout_s and settle_s must be > 0 s")
        if not 0 < self.min_coloured < 1:
            raise ValueError("min_coloured must be in (0, 1)")


def _rerun_command() -> list[str]:
    """The rerun-sdk's viewer binary (what its ``rerun`` script runs), else the script."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        exe = Path(spec.origin).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
        if exe.is_file():
            return [str(exe)]
    return [sys.executable, "-m", "rerun_cli"]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def viewer_url(web_port: int, grpc_port: int, theme: str = "dark") -> str:
    """The web viewer's address for the recording proxied on ``grpc_port``
    (browser state not persisted, so every opening shows the recording's blueprint)."""
    query = urllib.parse.urlencode({"url": f"rerun+http://127.0.0.1:{grpc_port}/proxy",
                                    "persist": "false", "theme": theme})
    return f"http://127.0.0.1:{web_port}/?{query}"


class ServedRecording:
    """``rerun --serve-web`` of one ``.rrd`` on loopback; a context manager.

    Parameters
    ----------
    rrd : path
    theme : str
    start_timeout_s : float
        Longest wait for the viewer's web page to answer, s.
    optimize : bool
        Serve a compacted copy (``rerun rrd optimize``, in a temporary directory): a
        node's recording holds one small chunk per entity and batch, which the viewer
        takes one by one, drawing a frame after each. Measured (TE, 2700 samples,
        software WebGL, 1600 x 1000 px, load 11 on 2 cores): 4078 chunks -> 165 in
        1.5 s, drawn 74 s after opening; uncompacted, a fifth of it was in after 4 min.

    Attributes
    ----------
    url : str
        The address to open (:func:`viewer_url`).
    """

    def __init__(self, rrd, theme: str = "dark", start_timeout_s: float = 30.0,
                 optimize: bool = True) -> None:
        import tempfile

        rrd = Path(rrd)
        if not rrd.is_file():
            raise FileNotFoundError(f"{rrd}: no such recording")
        self._tmp = tempfile.TemporaryDirectory(prefix="ssmpc-rrd-")
        if optimize:
            compact = Path(self._tmp.name) / rrd.name
            done = subprocess.run([*_rerun_command(), "rrd", "optimize", str(rrd), "-o",
                                   str(compact)], stdin=subprocess.DEVNULL,
                                  capture_output=True, timeout=300)
            if done.returncode != 0:
                self._tmp.cleanup()
                raise RuntimeError(f"rerun rrd optimize {rrd}: "
                                   f"{done.stderr.decode(errors='replace')[-800:]}")
            rrd = compact
        self.web_port, self.grpc_port = _free_port(), _free_port()
        self._log_path = Path(self._tmp.name) / "rerun.log"
        self._log = open(self._log_path, "wb")  # noqa: SIM115
        cmd = [*_rerun_command(), "--serve-web", "--bind", "127.0.0.1",
               "--web-viewer-port", str(self.web_port), "--port", str(self.grpc_port),
               str(rrd)]
        # its own process group: the viewer server goes with it, whatever it spawned
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        self.url = viewer_url(self.web_port, self.grpc_port, theme)
        t_end = time.monotonic() + start_timeout_s
        while True:
            if self.proc.poll() is not None:
                self._log.flush()
                out = self._log_path.read_bytes().decode(errors="replace")[-800:]
                self.close()
                raise RuntimeError(f"rerun --serve-web exited with {self.proc.returncode}: "
                                   f"{out}")
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.web_port}/",
                                            timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > t_end:
                self.close()
                raise RuntimeError(f"rerun web viewer not answering in {start_timeout_s:g} s")
            time.sleep(0.1)

    def close(self) -> None:
        """Stop the viewer server (its process group)."""
        stop_group(self.proc)
        self._log.close()
        self._tmp.cleanup()

    def __enter__(self) -> ServedRecording:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def decode_png(png: bytes) -> np.ndarray:
    """RGB pixels of a PNG, shape (height, width, 3), uint8."""
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"))


def coloured_fraction(rgb: np.ndarray) -> float:
    """Fraction of pixels whose saturation (max - min channel) exceeds
    :data:`COLOUR_SATURATION`; ``rgb`` shape (h, w, 3) uint8."""
    if rgb.size == 0:
        return 0.0
    c = rgb.astype(np.int16)
    sat = (c.max(axis=2) - c.min(axis=2)) / 255.0
    return float(np.mean(sat > COLOUR_SATURATION))


_PAGE_STATE = """(() => {
  const c = document.getElementById('the_canvas_id');
  const t = document.getElementById('center_text');
  return {canvas: !!c && c.classList.contains('visible'),
          message: t && t.classList.contains('visible') ? t.innerText : ''};
})()"""


def _alike(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and float(np.mean(np.any(a != b, axis=2))) < 0.002


def screenshot_recording(rrd, settings: ViewSettings | None = None,
                         browser: HeadlessChromium | None = None) -> tuple[bytes, dict]:
    """Serve ``rrd``, open it in headless Chromium and return the PNG once drawn.

    Parameters
    ----------
    rrd : path
        A Rerun recording (with its blueprint).
    settings : ViewSettings, optional
    browser : HeadlessChromium, optional
        A running browser to use, its viewport set to the settings' size; it must run at
        the settings' ``scale`` (default: one started and stopped here).

    Returns
    -------
    png : bytes
    info : dict
        ``load_s`` (wall seconds to the drawn, settled screen), ``coloured`` (its
        coloured fraction), ``canvas`` (the viewer's canvas shown), ``url``.

    Raises
    ------
    services.browser.BrowserUnavailable
        No Chromium.
    ValueError
        ``browser`` runs at another device scale factor than ``settings.scale``.
    NotDrawn
        (a TimeoutError) The recording was not drawn within ``timeout_s``: the message
        says what the page showed, ``png`` is the last screenshot.
    """
    s = settings or ViewSettings()
    own = browser is None
    if own:
        browser = HeadlessChromium(BrowserSettings(s.width, s.height, scale=s.scale))
    else:
        if browser.settings.scale != s.scale:
            raise ValueError(f"the browser runs at device scale {browser.settings.scale:g}, "
                             f"the view asks for {s.scale:g}")
        browser.set_viewport(s.width, s.height)
    try:
        with ServedRecording(rrd, theme=s.theme) as served:
            t0 = time.monotonic()
            browser.navigate(served.url)
            prev, state, frac, png = None, {}, 0.0, None
            while True:
                time.sleep(s.settle_s)
                state = browser.evaluate(_PAGE_STATE) or {}
                png = browser.screenshot()
                rgb = decode_png(png)
                frac = coloured_fraction(rgb)
                drawn = state.get("canvas") and frac >= s.min_coloured
                if drawn and prev is not None and _alike(prev, rgb):
                    return png, {"load_s": time.monotonic() - t0, "coloured": frac,
                                 "canvas": True, "url": served.url}
                prev = rgb if drawn else None
                if time.monotonic() - t0 > s.timeout_s:
                    raise NotDrawn(
                        f"viewer did not draw {rrd} in {s.timeout_s:g} s (canvas shown: "
                        f"{bool(state.get('canvas'))}, message: {state.get('message')!r}, "
                        f"coloured pixels {100 * frac:.2f} %)", png)
    finally:
        if own:
            browser.close()


# -- where the blueprint's panels are on the screen, and their titles -----------------

#: The viewer's own bars above and below the blueprint's panels, CSS px (rerun-sdk 0.41
#: web viewer, measured on 1280 x 800 screenshots): the top bar with the line under it,
#: and the collapsed time panel (play controls, time bar) with the line above it.
VIEWER_TOP_PX = 36
VIEWER_BOTTOM_PX = 29
#: A panel's title bar, CSS px from its top edge: the title's centre was measured 14-16
#: px below it (11 panels, 1280 x 800, device scale 1 and 2).
TITLE_BAR_PX = 30
#: How far right of its panel's left edge a title may start, CSS px (after the view's
#: icon: measured 28-29 px; OCR reads the icon into the title's first word at times).
TITLE_INDENT_PX = 48


@dataclass(frozen=True)
class Panel:
    """One view of a blueprint and the part of the panel area it gets.

    Attributes
    ----------
    name : str or None
        Its title (None: the viewer names it itself).
    kind : str
        The view's class, e.g. ``"TimeSeriesView"``, ``"TextLogView"``.
    box : tuple of float
        ``(x0, y0, x1, y1)``, fractions of the panel area (the viewer's window less
        its top bar and time panel), from its top left corner.
    """

    name: str | None
    kind: str
    box: tuple[float, float, float, float]


def _edges(n: int, shares, lo: float, hi: float) -> list[tuple[float, float]]:
    w = np.ones(n) if shares is None else np.asarray(list(shares), float)
    if w.shape != (n,) or not np.all(w > 0):
        raise ValueError(f"shares {shares!r} do not fit {n} parts")
    e = lo + (hi - lo) * np.concatenate(([0.0], np.cumsum(w))) / w.sum()
    return [(float(a), float(b)) for a, b in zip(e[:-1], e[1:])]


def panel_layout(blueprint) -> list[Panel]:
    """The views of a Rerun blueprint, depth first (the order they are declared), each
    with the part of the panel area that its containers' shares give it.

    Parameters
    ----------
    blueprint : rerun.blueprint.Blueprint
        With ``Horizontal`` (``column_shares``), ``Vertical`` (``row_shares``) and
        one-view ``Tabs`` containers; no shares means equal parts.

    Raises
    ------
    ValueError
        A ``Grid``, or ``Tabs`` with more than one view (only one would be shown).
    """
    import rerun.blueprint as rrb

    out: list[Panel] = []

    def walk(item, box):
        x0, y0, x1, y1 = box
        if isinstance(item, rrb.View):
            out.append(Panel(item.name, type(item).__name__, box))
            return
        kind = type(item).__name__
        parts = list(item.contents)
        if kind == "Horizontal":
            for part, (a, b) in zip(parts, _edges(len(parts), item.column_shares, x0, x1)):
                walk(part, (a, y0, b, y1))
        elif kind == "Vertical":
            for part, (a, b) in zip(parts, _edges(len(parts), item.row_shares, y0, y1)):
                walk(part, (x0, a, x1, b))
        elif kind == "Tabs" and len(parts) == 1:
            walk(parts[0], box)
        else:
            raise ValueError(f"{kind} container with {len(parts)} views: no fixed place "
                             f"on the screen for each")

    walk(blueprint.root_container, (0.0, 0.0, 1.0, 1.0))
    return out


def panel_boxes(blueprint, width: int, height: int,
                scale: float = 1.0) -> list[tuple[Panel, tuple[int, int, int, int]]]:
    """:func:`panel_layout` on the screen: each panel with its ``(x0, y0, x1, y1)`` in
    screenshot px, for a viewport of ``width`` x ``height`` CSS px at device scale
    ``scale`` (the viewer's bars, :data:`VIEWER_TOP_PX` and :data:`VIEWER_BOTTOM_PX`,
    left out)."""
    top, bottom = VIEWER_TOP_PX, height - VIEWER_BOTTOM_PX
    return [(p, (round(p.box[0] * width * scale),
                 round((top + p.box[1] * (bottom - top)) * scale),
                 round(p.box[2] * width * scale),
                 round((top + p.box[3] * (bottom - top)) * scale)))
            for p in panel_layout(blueprint)]


@dataclass(frozen=True)
class TitleCheck:
    """What :func:`check_titles` read.

    Attributes
    ----------
    found : dict
        Panel title -> box ``(x0, y0, x1, y1)`` px where it was read in its panel's
        title bar.
    misplaced : dict
        Panel title -> the boxes where it was read, none of them in its title bar.
    missing : tuple of str
        Titles not read anywhere.
    text : tuple of str
        Every line read (for messages).
    """

    found: dict
    misplaced: dict
    missing: tuple[str, ...]
    text: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """Every title read in its own panel's title bar."""
        return not self.misplaced and not self.missing

    def __str__(self) -> str:
        return (f"panel titles found {len(self.found)}, misplaced {dict(self.misplaced)}, "
                f"missing {list(self.missing)}")


def check_titles(png: bytes, blueprint, width: int, height: int, scale: float = 1.0,
                 ocr=None) -> TitleCheck:
    """Read a screenshot of the viewer and find each named panel's title in its title
    bar: the band :data:`TITLE_BAR_PX` below the panel's top edge (the title's centre
    in it), starting at most :data:`TITLE_INDENT_PX` right of its left edge.

    Parameters
    ----------
    png : bytes
        Screenshot, ``width * scale`` x ``height * scale`` px.
    blueprint : rerun.blueprint.Blueprint
        The layout the screen should show (:func:`panel_boxes`).
    width, height : int
        Viewport, CSS px.
    scale : float
        Device scale factor of the screenshot.
    ocr : services.screen_text.OcrSettings, optional
        Default: inverted, enlarged twice at scale 1, as is at scale 2 or more (the
        settings that read every title of the TE display in the module's measurement,
        :mod:`services.screen_text`).

    Raises
    ------
    services.screen_text.OcrUnavailable
        No tesseract.
    """
    from services.screen_text import OcrSettings, find_phrase, read_lines

    if ocr is None:
        ocr = OcrSettings(upscale=2 if scale < 2 else 1)
    lines = read_lines(png, ocr)
    found, misplaced, missing = {}, {}, []
    bar, indent = TITLE_BAR_PX * scale, TITLE_INDENT_PX * scale
    for panel, (x0, y0, x1, _) in panel_boxes(blueprint, width, height, scale):
        if panel.name is None:
            continue
        boxes = find_phrase(lines, panel.name)
        placed = [b for b in boxes
                  if y0 <= (b[1] + b[3]) / 2 <= y0 + bar and x0 <= b[0] <= x0 + indent
                  and b[2] <= x1]
        if placed:
            found[panel.name] = placed[0]
        elif boxes:
            misplaced[panel.name] = boxes
        else:
            missing.append(panel.name)
    return TitleCheck(found, misplaced, tuple(missing), tuple(ln.text for ln in lines))
