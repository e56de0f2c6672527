"""What a test does when a system program it needs (chromium, tesseract) is missing.

In CI (``SSMPC_CI`` set, as ``.ci/run`` does after installing them) the test fails with
the reason: a missing program there is a broken install step, not a reason to pass.
Elsewhere it is skipped with the same reason (``-ra`` lists it), so the suite runs on a
machine without them.
"""

import os

import pytest


def require(present: bool, reason: str) -> None:
    """Fail (in CI) or skip (elsewhere) the calling test with ``reason`` unless
    ``present``."""
    if present:
        return
    if os.environ.get("SSMPC_CI"):
        pytest.fail(f"{reason} (CI installs it in .ci/run)", pytrace=False)
    pytest.skip(reason)
