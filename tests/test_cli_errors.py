"""The command line says ``error:`` and exits 2 on an output it cannot write, never a
traceback (even as root, where os.access says yes to /proc)."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("argv", [
    ["sim", "te", "--hours", "0.01", "--out", "/proc/version"],
    ["sim", "cstr", "--op", "OPI", "--hours", "0.01", "--out", "/proc/version"],
    ["sim", "cstr", "--op", "OPI", "--hours", "0.01", "--out", "/nonexistent/dir/run.csv"],
])
def test_unwritable_output_is_an_error_line(argv):
    proc = subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: out:") and "Traceback" not in proc.stderr
