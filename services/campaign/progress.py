"""Campaign progress on the terminal (stderr): runs done / total, trips, errors, ETA.

On a terminal one line is redrawn in place after every finished run; otherwise
(a log file, a pipe) a line is written at most every :attr:`Progress.every_s`
seconds and once at the end. The ETA is the runs left times the mean wall time
per run finished in this session (runs of one campaign take similar times).
"""

from __future__ import annotations

import sys
import time
from typing import IO

__all__ = ["Progress", "format_duration"]


def format_duration(seconds: float) -> str:
    """``"1h02m"``, ``"3m20s"`` or ``"12s"``."""
    s = max(int(round(seconds)), 0)
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    if h:
        return f"{h}h{m:02d}m"
    if m:
        return f"{m}m{sec:02d}s"
    return f"{sec}s"


class Progress:
    """Counts finished runs and draws the progress line.

    Parameters
    ----------
    name : str
        Campaign name.
    total : int
        Runs of the campaign.
    skipped : int
        Runs already finished in the results directory (not run again).
    stream : file, optional
        Default stderr.
    """

    every_s = 5.0

    def __init__(self, name: str, total: int, skipped: int = 0, stream: IO[str] | None = None,
                 clock=time.monotonic) -> None:
        self.name = name
        self.total = int(total)
        self.done = int(skipped)
        self.skipped = int(skipped)
        self.trips = 0
        self.errors = 0
        self.stream = stream or sys.stderr
        self.clock = clock
        self.t0 = clock()
        self._last_line = -float("inf")
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def note_skipped_row(self, row: dict) -> None:
        """Count the trips of a run found finished."""
        self.trips += int(bool(row.get("tripped")))

    def line(self) -> str:
        executed = self.done - self.skipped
        elapsed = self.clock() - self.t0
        left = self.total - self.done
        if executed > 0 and left > 0:
            eta = f"ETA {format_duration(left * elapsed / executed)}"
        else:
            eta = "ETA -" if left else f"done in {format_duration(elapsed)}"
        skipped = f" ({self.skipped} already done)" if self.skipped else ""
        return (f"campaign {self.name}: {self.done}/{self.total} runs{skipped}, "
                f"{self.trips} trips, {self.errors} errors, {eta}")

    def update(self, row: dict) -> None:
        """One run finished (its row)."""
        self.done += 1
        self.trips += int(bool(row.get("tripped")))
        self.errors += int(bool(row.get("error")))
        if self.done < self.total:  # the last one is drawn by finish()
            self._draw(final=False)

    def start(self) -> None:
        if self.done < self.total:
            self._draw(final=False, force=True)

    def finish(self) -> None:
        self._draw(final=True, force=True)

    def _draw(self, final: bool, force: bool = False) -> None:
        now = self.clock()
        if self.tty:
            end = "\n" if final else ""
            self.stream.write("\r\x1b[K" + self.line() + end)
        elif force or final or now - self._last_line >= self.every_s:
            self.stream.write(self.line() + "\n")
            self._last_line = now
        else:
            return
        self.stream.flush()
