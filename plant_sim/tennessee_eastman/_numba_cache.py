"""Keep numba's on-disk cache of this package coherent across source edits.

numba keys a cached function on its own source file only. The compiled Euler
loop (``simulator.py``) embeds the model (``model.py``) and the constant offsets
(``constants.py``); after an edit of those files alone it would load stale
machine code that indexes the new constant vector with old offsets. This guard,
run once at import, compares a fingerprint (size and modification time) of all
source files of the package with the one stored beside numba's cache files and,
when they differ, removes the package's cache files so that everything is
recompiled once. Failures (read-only install, races with another process) are
ignored: numba then recompiles or uses its own checks.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

_STAMP = "te_sources.stamp"


def _fingerprint(pkg: Path) -> str:
    parts = []
    for src in sorted(pkg.glob("*.py")):
        st = src.stat()
        parts.append(f"{src.name}:{st.st_size}:{st.st_mtime_ns}")
    return "\n".join(parts)


def ensure_coherent_cache() -> None:
    """Drop this package's numba cache files if any source file changed since they were made."""
    with contextlib.suppress(OSError):
        pkg = Path(__file__).resolve().parent
        cache = pkg / "__pycache__"
        stamp = cache / _STAMP
        current = _fingerprint(pkg)
        if stamp.is_file() and stamp.read_text() == current:
            return
        cache.mkdir(exist_ok=True)
        for pattern in ("*.nbi", "*.nbc"):
            for f in cache.glob(pattern):
                with contextlib.suppress(OSError):
                    f.unlink()
        tmp = cache / f".{_STAMP}.tmp"
        tmp.write_text(current)
        tmp.replace(stamp)


ensure_coherent_cache()
