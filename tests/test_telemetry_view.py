"""The browser-side helpers of the trend display without the viewer: settings refuse bad
values, the coloured-pixel measure tells grey interface from drawn series, a missing
recording or browser is a clear error, a device scale enlarges the screenshot and not
the layout (a blank page), the blueprint's shares give each panel its place, and titles
drawn in their panels' title bars pass the OCR check while swapped, misplaced or absent
ones do not."""

import io

import numpy as np
import pytest
from system_tools import require

from services.browser import BrowserSettings, BrowserUnavailable, HeadlessChromium
from services.telemetry_view import ServedRecording, ViewSettings, coloured_fraction, viewer_url


@pytest.mark.parametrize("kw", [{"width": 100}, {"height": 5000}, {"width": 800.5},
                                {"start_timeout_s": 0}, {"scale": 0.5}, {"scale": 5}])
def test_browser_settings_refuse_bad_values(kw):
    with pytest.raises(ValueError):
        BrowserSettings(**kw)


@pytest.mark.parametrize("kw", [{"theme": "blue"}, {"timeout_s": -1}, {"min_coloured": 1.5},
                                {"width": 10}, {"scale": 8}])
def test_view_settings_refuse_bad_values(kw):
    with pytest.raises(ValueError):
        ViewSettings(**kw)


def test_grey_interface_is_not_coloured_and_series_are():
    img = np.full((100, 200, 3), 30, np.uint8)
    img[10:20, :100] = (200, 200, 200)  # light grey text and frames
    assert coloured_fraction(img) == 0.0
    img[50, :] = (80, 160, 240)  # one blue series line, 200 of 20000 pixels
    img[60, :50] = (200, 120, 40)  # a quarter-width orange line, 50 pixels
    assert coloured_fraction(img) == pytest.approx(250 / 20000)
    assert coloured_fraction(np.zeros((0, 0, 3), np.uint8)) == 0.0


def test_viewer_url_points_at_the_loopback_proxy():
    url = viewer_url(9090, 9876, "light")
    assert url.startswith("http://127.0.0.1:9090/?")
    assert "url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy" in url
    assert "persist=false" in url and "theme=light" in url


def test_missing_recording_and_browser_are_clear_errors(tmp_path, monkeypatch):
    with pytest.raises(FileNotFoundError, match="no such recording"):
        ServedRecording(tmp_path / "absent.rrd")
    monkeypatch.setenv("SSMPC_CHROMIUM", str(tmp_path / "no-chromium"))
    with pytest.raises(BrowserUnavailable, match="no chromium"):
        HeadlessChromium()


def _unit_blueprint():
    """A unit's trend display (services.telemetry.blueprint): CV ``y1`` tracked, ``y2``
    limited, ``y3`` neither; one MV with a range."""
    from controller.units.variables import VariableInfo
    from services.telemetry import blueprint

    inf = float("inf")
    variables = [VariableInfo("y1", "XMEAS 40", "product G", "mol%", "cv", -inf, inf),
                 VariableInfo("y2", "XMEAS 7", "reactor pressure", "kPa gauge", "cv",
                              -inf, 2950.0),
                 VariableInfo("y3", "XMEAS 9", "reactor temperature", "degC", "cv", -inf, inf),
                 VariableInfo("u1", "XMV 10", "cooling water", "%", "mv", 0.0, 100.0)]
    return blueprint("te", ["y1", "y2", "y3"], ["y1"], variables)


def test_the_layout_has_key_cvs_left_and_the_rest_right_in_shares():
    from services.telemetry_view import panel_layout

    panels = panel_layout(_unit_blueprint())
    left = [p for p in panels if p.box[2] <= 0.6 + 1e-9]
    right = [p for p in panels if p.box[0] >= 0.6 - 1e-9]
    assert len(left) + len(right) == len(panels) == 7
    # the tracked CV, then the limited one; each an equal row of the 3/5 column
    assert [p.name for p in left] == ["XMEAS 40 product G (mol%)",
                                      "XMEAS 7 reactor pressure (kPa gauge)"]
    assert left[0].box == pytest.approx((0.0, 0.0, 0.6, 0.5))
    assert left[1].box == pytest.approx((0.0, 0.5, 0.6, 1.0))
    assert [(p.name, p.kind) for p in right] == [
        ("MVs, % of range", "TimeSeriesView"), ("active model", "TimeSeriesView"),
        ("log10 J (eq. 4.6)", "TimeSeriesView"), ("events", "TextLogView"),
        ("timing (ms)", "TimeSeriesView")]
    tops = [0.0, 3 / 11, 5 / 11, 7 / 11, 9 / 11, 1.0]  # rows 3:2:2:2:2
    for p, y0, y1 in zip(right, tops[:-1], tops[1:]):
        assert p.box == pytest.approx((0.6, y0, 1.0, y1))


def test_a_layout_without_fixed_places_is_refused():
    import rerun.blueprint as rrb

    from services.telemetry_view import panel_boxes, panel_layout

    with pytest.raises(ValueError, match="Grid"):
        panel_layout(rrb.Blueprint(rrb.Grid(rrb.TextLogView(name="a"),
                                            rrb.TextLogView(name="b"))))
    with pytest.raises(ValueError, match="Tabs"):
        panel_layout(rrb.Blueprint(rrb.Tabs(rrb.TextLogView(name="a"),
                                            rrb.TextLogView(name="b"))))
    (only,) = panel_boxes(rrb.Blueprint(rrb.TextLogView(name="a")), 800, 600)
    assert only[1] == (0, 36, 800, 571)  # below the top bar, above the time panel


def _screen(titles, size=(800, 600)):
    """A dark viewer-like PNG with light 14 px titles at [(text, x, y)]."""
    from PIL import Image, ImageDraw, ImageFont

    im = Image.new("RGB", size, (13, 13, 13))
    draw = ImageDraw.Draw(im)
    font = ImageFont.load_default(size=14)
    for text, x, y in titles:
        draw.text((x, y), text, fill=(220, 220, 220), font=font)
    buf = io.BytesIO()
    im.save(buf, "PNG")
    return buf.getvalue()


def _two_columns():
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Horizontal(
        rrb.TimeSeriesView(name="reactor level"),
        rrb.Vertical(rrb.TextLogView(name="events"), rrb.TimeSeriesView(name="timing (ms)")),
        column_shares=[3, 2]))


@pytest.fixture
def ocr():
    from services.screen_text import find_tesseract

    require(find_tesseract() is not None,
            "no tesseract on PATH (apt-get install tesseract-ocr, or set SSMPC_TESSERACT)")


def test_titles_in_their_title_bars_pass(ocr):
    from services.telemetry_view import check_titles

    # 800 x 600: panels below y 36 and above 571; left column x 0-480, right from 480,
    # its second row from 36 + 535 / 2 = 303.5; titles 28 px in, 8 px down
    png = _screen([("reactor level", 28, 44), ("events", 508, 44), ("timing (ms)", 508, 312),
                   ("reactor level", 60, 120)])  # the legend repeats the title lower down
    r = check_titles(png, _two_columns(), 800, 600)
    assert r.ok, r
    assert set(r.found) == {"reactor level", "events", "timing (ms)"}
    assert r.found["timing (ms)"][1] == pytest.approx(312, abs=4)


def test_titles_swapped_misplaced_or_absent_fail(ocr):
    from services.telemetry_view import check_titles

    swapped = _screen([("reactor level", 28, 44), ("timing (ms)", 508, 44),
                       ("events", 508, 312)])
    r = check_titles(swapped, _two_columns(), 800, 600)
    assert not r.ok and set(r.misplaced) == {"events", "timing (ms)"}, r
    # the left title only in the plot, below its title bar; the right column missing
    r = check_titles(_screen([("reactor level", 60, 120)]), _two_columns(), 800, 600)
    assert not r.ok and set(r.misplaced) == {"reactor level"}
    assert set(r.missing) == {"events", "timing (ms)"}
    r = check_titles(_screen([]), _two_columns(), 800, 600)
    assert len(r.missing) == 3 and not r.found


def test_device_scale_multiplies_the_screenshot_not_the_layout():
    from services.browser import find_chromium
    from services.telemetry_view import decode_png

    require(find_chromium() is not None,
            "no chromium on PATH (apt-get install chromium, or set SSMPC_CHROMIUM)")
    try:
        browser = HeadlessChromium(BrowserSettings(400, 300, scale=2))
    except BrowserUnavailable as exc:
        require(False, f"chromium does not run here: {exc}")
    try:
        browser.navigate("about:blank")
        size = browser.evaluate("[innerWidth, innerHeight, devicePixelRatio]")
        shot = decode_png(browser.screenshot())
    finally:
        browser.close()
    assert size == [400, 300, 2]  # laid out at 400 x 300 CSS px
    assert shot.shape == (600, 800, 3)
