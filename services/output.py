"""Command-line output conventions: one JSON object on the last stdout line,
errors on stderr with a non-zero exit, and files written atomically."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

__all__ = ["CLIError", "emit_json", "atomic_output", "check_writable", "to_jsonable"]


class CLIError(Exception):
    """A user error: printed as ``error: <message>`` on stderr, exit code :attr:`code`."""

    def __init__(self, message: str, code: int = 2) -> None:
        super().__init__(message)
        self.code = code


def to_jsonable(obj):
    """Convert numpy scalars/arrays and non-finite floats into plain JSON values."""
    try:
        import numpy as np
    except ImportError:  # pragma: no cover
        np = None
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if np is not None and isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if np is not None and isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def emit_json(obj, stream: IO[str] | None = None) -> None:
    """Print ``obj`` as one JSON line (the last line of stdout by convention)."""
    stream = stream or sys.stdout
    stream.write(json.dumps(to_jsonable(obj), allow_nan=False) + "\n")
    stream.flush()


def check_writable(path: str | os.PathLike, field: str = "out") -> Path:
    """Fail early, before any work, if ``path`` cannot be written."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise CLIError(f"{field}: directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"{field}: directory {str(parent)!r} is not writable")
    if p.exists() and p.is_dir():
        raise CLIError(f"{field}: {str(p)!r} is a directory")
    # os.access says yes to root everywhere (/proc, read-only mounts): try it for real
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".probe", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CLIError(f"{field}: cannot write in {str(parent)!r}: {exc.strerror or exc}") from exc
    return p


def _current_umask() -> int:
    """The process umask, read without changing it (os.umask would race other threads)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, mode: str = "w", field: str = "out") -> Iterator[IO]:
    """Write to a temporary file beside ``path`` and rename it on success.

    On any exception the temporary file is removed, so no partial output is left.
    """
    p = check_writable(path, field)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".part", dir=p.parent or ".")
    except OSError as exc:
        raise CLIError(f"{field}: cannot write {str(p)!r}: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        # mkstemp creates 0600; give the file the permissions a plain open() would.
        os.chmod(tmp, 0o666 & ~_current_umask())
        os.replace(tmp, p)
    except OSError as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise CLIError(f"{field}: cannot write {str(p)!r}: {exc.strerror or exc}") from exc
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
