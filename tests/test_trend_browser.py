"""The trend display in a real browser: a TE 0 -> 2 recording served by Rerun's web viewer
(``rerun --serve-web`` on loopback) and opened in headless Chromium.

What is checked: the viewer's page loads, its wasm app starts and shows its canvas (DOM:
the canvas visible, no loading or crash message), and the screenshot shows the panels of
the recording's blueprint BY NAME, where the blueprint puts them. The viewer draws the
titles into its canvas and exposes no DOM or accessibility node for them, so they are read
with OCR (tesseract, services.screen_text): the names and places come from the blueprint
itself (services.telemetry.blueprint, as the controller node records it, walked by
services.telemetry_view.panel_layout: one panel per key CV in the left 3/5 column, the
MVs, active model, log10 J, events and timing on the right in shares 3:2:2:2:2), and each
name must be read in its own panel's title bar (check_titles); the key CVs' titles are
then read top to bottom in the left column in the blueprint's order, the others so in the
right. Two screens must not pass that check: the viewer's loading page (nothing read),
and the real screenshot held against a blueprint that renames one panel (a key CV's
description changed by one letter: that panel is reported missing, the others found).
Measured at 1280 x 800, device scale 1, read enlarged x2: 11 of 11 titles, each in its own
title bar, in 12 renders of 5 recordings (services.screen_text).

Besides the names, each panel region holds coloured pixels (series lines, legend dots; the
viewer's own interface is grey; 1.0-5.3 % of each plot region with the recording drawn,
0.0 % with the loading page or a recording without data), the events panel green ones
(the INFO level of the transition's events), and the first CV panel's coloured pixels
spread over most of its width (the plots span the run, not a window around the time
cursor). A crashed viewer removes its canvas (the DOM check).

Kept as artifacts, in ``$SSMPC_ARTIFACTS`` when that is set, else in pytest's tmp dir
(paths printed): ``trend_display.png`` (the screenshot), ``trend_display_text.txt`` (the
lines OCR read), ``trend_display_loading.png`` (the loading page). Without chromium or
tesseract the test fails in CI (``SSMPC_CI``, set by ``.ci/run``, which installs both)
and is skipped elsewhere, with the reason (tests/system_tools.py).
"""

import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from system_tools import require

from services.browser import BrowserUnavailable, HeadlessChromium, find_chromium
from services.screen_text import find_tesseract
from services.telemetry import blueprint
from services.telemetry_view import (
    TITLE_BAR_PX,
    NotDrawn,
    ServedRecording,
    ViewSettings,
    check_titles,
    coloured_fraction,
    decode_png,
    panel_boxes,
    screenshot_recording,
)

pytestmark = [pytest.mark.slow, pytest.mark.integration, pytest.mark.timeout(420)]

WIDTH, HEIGHT = 1280, 800
LEFT_SHARE = 3 / 5  # the key CVs' column
MIN_COLOURED = 0.001  # of a panel region's pixels; measured 0.3-5 % with the recording drawn


def _plot_regions(bp, width, height):
    """[(panel name, (x0, y0, x1, y1))] of the blueprint's panels without their title
    bars, each inset by 10 %."""
    out = []
    for panel, (x0, y0, x1, y1) in panel_boxes(bp, width, height):
        y0 += TITLE_BAR_PX
        w, h = x1 - x0, y1 - y0
        out.append((panel.name, (int(x0 + 0.1 * w), int(y0 + 0.1 * h), int(x1 - 0.1 * w),
                                 int(y1 - 0.1 * h))))
    return out


def _te_recording(tmp_path):
    """A TE recording as ``ssmpc controller`` writes it (tags, units, limits): start, the
    request for mode 2, two process hours of the grade change. Returns its path, the
    blueprint it holds (built as the controller node builds it), and the unit's
    variables."""
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
    variables = unit_variables(h.cfg, plant)

    def make(variables):
        return blueprint(h.cfg.unit, info.cv_names, h.cfg.track or None, variables)

    return tmp_path / "te.rrd", make, variables


def _artifact_dir(tmp_path):
    d = os.environ.get("SSMPC_ARTIFACTS")
    if d:
        Path(d).mkdir(parents=True, exist_ok=True)
        return Path(d)
    return tmp_path


def _loading_page(rrd, browser, attempts: int = 5):
    """A screenshot of the viewer's page before its app has drawn anything, and whether
    its canvas was shown then. On a fast load the app may show its canvas between the
    page's load and the screenshot (seen once in CI): then the page is loaded again, up
    to ``attempts`` times, and the last one is returned as it was."""
    with ServedRecording(rrd) as served:
        for _ in range(attempts):
            browser.navigate(served.url)
            t_end = time.monotonic() + 30
            while True:
                try:  # the old document's context may go away while asked
                    if browser.evaluate("!!document.getElementById('the_canvas_id')"):
                        break
                except RuntimeError:
                    pass
                assert time.monotonic() < t_end, "the viewer's page did not load in 30 s"
                time.sleep(0.05)
            png = browser.screenshot()
            shown = browser.evaluate(
                "document.getElementById('the_canvas_id').classList.contains('visible')")
            browser.navigate("about:blank")
            if not shown:
                break
    return png, shown


def test_trend_display_shows_the_blueprint_panels_by_name(tmp_path):
    require(find_chromium() is not None,
            "no chromium on PATH (apt-get install chromium, or set SSMPC_CHROMIUM)")
    require(find_tesseract() is not None,
            "no tesseract on PATH (apt-get install tesseract-ocr, or set SSMPC_TESSERACT)")
    try:
        browser = HeadlessChromium()
    except BrowserUnavailable as exc:
        require(False, f"chromium does not run here: {exc}")
    art = _artifact_dir(tmp_path)
    out = art / "trend_display.png"
    try:
        rrd, make_blueprint, variables = _te_recording(tmp_path)
        browser.set_viewport(WIDTH, HEIGHT)
        loading, loading_canvas = _loading_page(rrd, browser)
        (art / "trend_display_loading.png").write_bytes(loading)
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

    # the panels by name, each in its own title bar
    bp = make_blueprint(variables)
    titles = check_titles(png, bp, WIDTH, HEIGHT)
    (art / "trend_display_text.txt").write_text("\n".join(titles.text) + "\n")
    print(f"text read: {art / 'trend_display_text.txt'}")
    assert titles.ok, f"{titles}; see {out}"
    panels = [p for p, _ in panel_boxes(bp, WIDTH, HEIGHT)]
    left = [p.name for p in panels if p.box[2] <= LEFT_SHARE + 1e-9]
    right = [p.name for p in panels if p.box[0] >= LEFT_SHARE - 1e-9]
    assert len(left) >= 2 and len(right) == 5  # the tracked G in product, the limited CVs
    assert set(titles.found) == set(left) | set(right)
    # read in the left column top to bottom in the blueprint's order, and so in the right
    for names, in_column in ((left, lambda x: x < LEFT_SHARE * WIDTH),
                             (right, lambda x: x >= LEFT_SHARE * WIDTH)):
        boxes = [titles.found[n] for n in names]
        assert all(in_column(b[0]) for b in boxes), f"{titles.found}; see {out}"
        tops = [b[1] for b in boxes]
        assert tops == sorted(tops), f"{titles.found}; see {out}"

    # not passed by: the loading page, nor a blueprint with one panel renamed
    assert not loading_canvas
    before = check_titles(loading, bp, WIDTH, HEIGHT)
    assert not before.found and not before.ok, before
    first = next(v for v in variables
                 if v.kind == "cv" and left[0].startswith(f"{v.tag} {v.description}"))
    renamed = [replace(v, description=v.description.replace(" G", " H"))
               if v is first else v for v in variables]
    other = check_titles(png, make_blueprint(renamed), WIDTH, HEIGHT)
    assert not other.ok and len(other.missing) == 1, other
    assert other.missing[0] != left[0] and other.missing[0].startswith(first.tag)
    assert set(other.found) == set(titles.found) - {left[0]}

    # data drawn in every panel
    regions = _plot_regions(bp, WIDTH, HEIGHT)
    fractions = {name: coloured_fraction(rgb[y0:y1, x0:x1])
                 for name, (x0, y0, x1, y1) in regions}
    empty = [n for n, f in fractions.items() if f < MIN_COLOURED]
    assert not empty, f"panels without a drawn series: {empty} ({fractions}); see {out}"
    boxes = dict(regions)
    x0, y0, x1, y1 = boxes["events"]
    ev = rgb[y0:y1, x0:x1].astype(np.int16)
    green = (ev[..., 1] > ev[..., 0] + 60) & (ev[..., 1] > ev[..., 2] + 60)
    assert green.sum() >= 20, f"no INFO event drawn in the events panel; see {out}"
    # the plots span the run: the first CV panel's coloured pixels cover most of its width
    x0, y0, x1, y1 = boxes[left[0]]
    c = rgb[y0:y1, x0:x1].astype(np.int16)
    cols = np.flatnonzero(((c.max(axis=2) - c.min(axis=2)) > 64).any(axis=0))
    assert cols.size and (cols[-1] - cols[0]) > 0.6 * (x1 - x0), f"see {out}"
