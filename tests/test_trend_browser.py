"""The trend display in a real browser: a TE 0 -> 2 recording served by Rerun's web viewer
(``rerun --serve-web`` on loopback) and opened in headless Chromium.

What is checked, and what is not: the viewer's page loads, its wasm app starts and shows
its canvas (DOM: the canvas visible, no loading or crash message); the screenshot shows
the recording drawn in the blueprint's layout. The viewer draws panel titles into the
canvas and exposes no DOM or accessibility node for them (its accessibility tree holds
the page title only), so the panels are not found by name: the test takes the blueprint's
panels (services.telemetry.blueprint: one per key CV on the left, 3/5 of the width; the
MVs, active model, log10 J, events and timing on the right, in shares 3:2:2:2:1) and
checks that each of those regions holds coloured pixels (series lines, legend dots; the
viewer's own interface is grey), and the events panel green ones (the INFO level of the
transition's events; its header's blue highlight is there without any). Measured at
1600 x 1000: 1.0-5.3 % of each plot region coloured with the TE recording drawn; 0.0 %
with the loading page, and 0.0 % (events: 1.7 % blue, no green) with a recording that
holds the blueprint and no data. A crashed viewer removes its canvas (the DOM check).
It also checks that the plots span the process-time range of the run rather than a
window around the time cursor (the coloured pixels of the first CV panel spread over
most of its width). The screenshot is kept: ``$SSMPC_ARTIFACTS/trend_display.png``
when that is set, else in pytest's tmp dir; its path is printed.
"""

import os
from pathlib import Path

import numpy as np
import pytest

from services.browser import BrowserUnavailable, HeadlessChromium, find_chromium
from services.telemetry import key_cvs
from services.telemetry_view import (
    NotDrawn,
    ViewSettings,
    coloured_fraction,
    decode_png,
    screenshot_recording,
)

pytestmark = [pytest.mark.slow, pytest.mark.integration, pytest.mark.timeout(300)]

WIDTH, HEIGHT = 1280, 800
#: Right-hand column of the blueprint, top to bottom, and its row shares.
RIGHT_PANELS = ("MVs, % of range", "active model", "log10 J (eq. 4.6)", "events", "timing (ms)")
RIGHT_SHARES = (3, 2, 2, 2, 1)
LEFT_SHARE = 3 / 5
# The viewer's top bar and the collapsed time panel, px at device scale 1 (measured on
# rerun 0.41 screenshots; the regions checked are inset well inside the panels).
TOP_BAR_PX, TIME_PANEL_PX = 36, 40
MIN_COLOURED = 0.001  # of a panel region's pixels; measured 0.3-5 % with the recording drawn


def _panel_regions(n_cvs, width, height):
    """{panel: (x0, y0, x1, y1)} of the blueprint's panels, each inset by 10 % and its
    title bar."""
    top, bottom = TOP_BAR_PX, height - TIME_PANEL_PX
    split = int(width * LEFT_SHARE)

    def column(x0, x1, shares):
        edges = top + (bottom - top) * np.cumsum((0, *shares)) / sum(shares)
        out = []
        for a, b in zip(edges[:-1], edges[1:]):
            h, w = b - a, x1 - x0
            out.append((int(x0 + 0.1 * w), int(a + 24 + 0.1 * h), int(x1 - 0.1 * w),
                        int(b - 0.1 * h)))
        return out

    left = column(0, split, (1,) * n_cvs)
    right = column(split, width, RIGHT_SHARES)
    return left, dict(zip(RIGHT_PANELS, right))


def _te_recording(tmp_path):
    """A TE recording as ``ssmpc controller`` writes it (tags, units, limits): start, the
    request for mode 2, two process hours of the grade change. Returns its path and the
    key CVs (one panel each)."""
    from test_service_loop import Harness

    h = Harness(tmp_path, unit="te", speed=1_000.0, telemetry=True, strategy="ssmpc",
                telemetry_variables=True)
    try:
        h.wait_samples(5, timeout=90)
        tid = h.query("transition", {"op": "create", "grade": "mode2"}).data["id"]
        h.wait_samples(200, timeout=60)  # 2 process hours of the grade change
        assert h.query("transition", {"op": "get", "id": tid}).data["state"] in (
            "running", "settled")
    finally:
        h.close()
    from controller.units.config import build_plant, unit_info
    from controller.units.variables import unit_variables

    plant = build_plant(h.cfg)
    info = unit_info(h.cfg, plant)
    keys = key_cvs(info.cv_names, h.cfg.track or None, unit_variables(h.cfg, plant))
    return tmp_path / "te.rrd", keys


def _artifact_dir(tmp_path):
    d = os.environ.get("SSMPC_ARTIFACTS")
    if d:
        Path(d).mkdir(parents=True, exist_ok=True)
        return Path(d)
    return tmp_path


def test_trend_display_renders_in_headless_chromium(tmp_path):
    if find_chromium() is None:
        pytest.skip("no chromium on PATH (apt-get install chromium, or set SSMPC_CHROMIUM)")
    try:
        browser = HeadlessChromium()
    except BrowserUnavailable as exc:
        pytest.skip(f"chromium does not run here: {exc}")
    out = _artifact_dir(tmp_path) / "trend_display.png"
    try:
        rrd, keys = _te_recording(tmp_path)
        png, info = screenshot_recording(rrd, ViewSettings(WIDTH, HEIGHT, timeout_s=240.0),
                                         browser=browser)
    except NotDrawn as exc:
        if exc.png:
            out.write_bytes(exc.png)
        raise AssertionError(f"{exc}; last screenshot: {out}") from exc
    finally:
        browser.close()
    out.write_bytes(png)
    print(f"trend display screenshot: {out} (viewer drew it in {info['load_s']:.1f} s)")
    assert info["canvas"]
    rgb = decode_png(png)
    assert rgb.shape == (HEIGHT, WIDTH, 3)
    assert len(keys) >= 2  # the tracked G in product and the limited ones
    left, right = _panel_regions(len(keys), WIDTH, HEIGHT)
    fractions = {}
    for name, (x0, y0, x1, y1) in [*zip(keys, left), *right.items()]:
        fractions[name] = coloured_fraction(rgb[y0:y1, x0:x1])
    empty = [n for n, f in fractions.items() if f < MIN_COLOURED]
    assert not empty, f"panels without a drawn series: {empty} ({fractions}); see {out}"
    x0, y0, x1, y1 = right["events"]
    ev = rgb[y0:y1, x0:x1].astype(np.int16)
    green = (ev[..., 1] > ev[..., 0] + 60) & (ev[..., 1] > ev[..., 2] + 60)
    assert green.sum() >= 20, f"no INFO event drawn in the events panel; see {out}"
    # the plots span the run: the first CV panel's coloured pixels cover most of its width
    x0, y0, x1, y1 = left[0]
    c = rgb[y0:y1, x0:x1].astype(np.int16)
    cols = np.flatnonzero(((c.max(axis=2) - c.min(axis=2)) > 64).any(axis=0))
    assert cols.size and (cols[-1] - cols[0]) > 0.6 * (x1 - x0), f"see {out}"
