"""Make docs/trend_display.png: the Rerun trend display of a TE grade change 0 -> 2.

Runs what a user runs: ``ssmpc up --unit te --speed 300`` in a temporary state
directory, a REST request for grade ``mode2`` once the API answers (the plant has run
a few process hours by then), the process until the transition has settled and
``--after-h`` process hours more, Ctrl-C; then serves the recording ``ssmpc-te.rrd``
with Rerun's web viewer and screenshots it in headless Chromium
(services.telemetry_view). About 4 wall minutes for the run, 1-5 for the viewer.
Needs ``chromium`` on PATH (Debian: ``apt-get install chromium``) or
``SSMPC_CHROMIUM``.

    python docs/trend_screenshot.py                    # writes docs/trend_display.png
    python docs/trend_screenshot.py --keep te-run      # keep the state dir and .rrd
    python docs/trend_screenshot.py --rrd te-run/ssmpc-te.rrd   # screenshot it again

The PNG is reduced to a 256-colour palette by octree quantization: measured at 1600 x
1000, 297 kB as drawn, 75 kB reduced, and the events' green INFO text still green
(median-cut quantization turned it grey).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.browser import BrowserUnavailable, find_chromium  # noqa: E402
from services.telemetry_view import NotDrawn, ViewSettings, screenshot_recording  # noqa: E402

TE_SAMPLE_S = 36.0  # the TE unit's controller sample period (facts te.md)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _http(method: str, url: str, body: dict | None = None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"content-type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as r:
        return r.status, dict(r.headers), json.loads(r.read() or b"null")


def record(state_dir: Path, after_h: float, speed: float, timeout_s: float) -> Path:
    """Run ``ssmpc up`` through a TE 0 -> 2 transition; return the recording's path."""
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("SSMPC_API_TOKEN", None)  # loopback, no token: writes allowed
    up = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--unit", "te",
                           "--speed", str(speed), "--port", str(port),
                           "--state-dir", str(state_dir)], env=env, cwd=state_dir,
                          start_new_session=True)
    base = f"http://127.0.0.1:{port}/api/v1/units/te"
    t_end = time.monotonic() + timeout_s
    try:
        while True:
            if up.poll() is not None:
                raise SystemExit(f"error: ssmpc up exited with {up.returncode}")
            try:
                if _http("GET", base + "/status")[0] == 200:
                    break
            except OSError:
                pass
            if time.monotonic() > t_end:
                raise SystemExit("error: ssmpc up not ready in time")
            time.sleep(1.0)
        code, headers, _ = _http("POST", base + "/transitions", {"grade": "mode2"})
        if code != 202:
            raise SystemExit(f"error: transition request answered {code}")
        where = f"http://127.0.0.1:{port}" + headers["location"]
        while True:
            view = _http("GET", where)[2]
            if view["state"] not in ("pending", "running"):
                break
            if time.monotonic() > t_end:
                raise SystemExit("error: transition still running at the timeout")
            time.sleep(1.0)
        print(f"transition {view['state']}", file=sys.stderr)
        until = _http("GET", base + "/status")[2]["sample"] + after_h * 3600 / TE_SAMPLE_S
        while _http("GET", base + "/status")[2]["sample"] < until:
            if time.monotonic() > t_end:
                break
            time.sleep(0.5)
    finally:
        os.killpg(up.pid, signal.SIGINT)  # Ctrl-C: up stops its nodes, the .rrd is closed
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGKILL)
            up.wait(10)
    return state_dir / "ssmpc-te.rrd"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "trend_display.png")
    ap.add_argument("--keep", type=Path, help="state directory to keep (default: temporary)")
    ap.add_argument("--rrd", type=Path, help="screenshot this recording (no run)")
    ap.add_argument("--after-h", type=float, default=2.0,
                    help="process hours recorded after the transition settled (default 2)")
    ap.add_argument("--speed", type=float, default=300.0,
                    help="ssmpc up --speed: process seconds per wall second (default 300)")
    ap.add_argument("--width", type=int, default=1600)
    ap.add_argument("--height", type=int, default=1000)
    ap.add_argument("--theme", choices=("dark", "light"), default="dark")
    ap.add_argument("--timeout", type=float, default=900.0, help="wall seconds for the run")
    args = ap.parse_args(argv)
    try:
        settings = ViewSettings(args.width, args.height, args.theme, timeout_s=600.0)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if find_chromium() is None:
        print("error: no chromium on PATH (apt-get install chromium, or set SSMPC_CHROMIUM)",
              file=sys.stderr)
        return 2
    from PIL import Image

    with tempfile.TemporaryDirectory(prefix="ssmpc-trend-") as tmp:
        if args.rrd is not None:
            if not args.rrd.is_file():
                print(f"error: {args.rrd}: no such recording", file=sys.stderr)
                return 2
            rrd = args.rrd
        else:
            state = args.keep or Path(tmp)
            state.mkdir(parents=True, exist_ok=True)
            rrd = record(state.resolve(), args.after_h, args.speed, args.timeout)
        try:
            png, info = screenshot_recording(rrd, settings)
        except (BrowserUnavailable, NotDrawn) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        import io

        im = Image.open(io.BytesIO(png)).convert("RGB")
        im.quantize(colors=256, method=Image.Quantize.FASTOCTREE).save(args.out, optimize=True)
    print(f"{args.out}: {args.out.stat().st_size / 1e3:.0f} kB, viewer drew it in "
          f"{info['load_s']:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
