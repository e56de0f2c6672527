"""The browser-side helpers of the trend display without a browser: settings refuse bad
values, the coloured-pixel measure tells grey interface from drawn series, and a missing
recording or browser is a clear error."""

import numpy as np
import pytest

from services.browser import BrowserSettings, BrowserUnavailable, HeadlessChromium
from services.telemetry_view import ServedRecording, ViewSettings, coloured_fraction, viewer_url


@pytest.mark.parametrize("kw", [{"width": 100}, {"height": 5000}, {"width": 800.5},
                                {"start_timeout_s": 0}])
def test_browser_settings_refuse_bad_values(kw):
    with pytest.raises(ValueError):
        BrowserSettings(**kw)


@pytest.mark.parametrize("kw", [{"theme": "blue"}, {"timeout_s": -1}, {"min_coloured": 1.5},
                                {"width": 10}])
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
