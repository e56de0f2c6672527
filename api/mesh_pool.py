"""The api node's own, bounded pool for Zenoh queries, off the request thread pool.

A Zenoh query blocks its thread until the node answers or the timeout ends. Run
on the server's request thread pool (anyio's, 40 threads), 40 queries to a
controller that never answers would make every other request, ``/health``
included, wait for them. So the handlers are coroutines and the queries run here:
at most ``concurrency`` at once on this pool's threads, at most ``backlog`` more
waiting for one, and a query beyond that is refused at once with 503 (the api is
busy; the client retries). ``/health`` and the unit list never query the mesh.

Measured on the 2-core machine: with 200 concurrent GETs to a unit whose controller
never answers, ``/health`` answered in a few ms (``tests/test_api_hardening.py``
prints it); before, it waited 9.6 s behind them.
"""

from __future__ import annotations

import asyncio
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from api.mesh import MeshError

__all__ = ["MeshLimits", "MeshPool"]


@dataclass(frozen=True)
class MeshLimits:
    """How many Zenoh queries the api node runs at once and lets wait.

    Parameters
    ----------
    concurrency : int
        Queries under way at once (threads of the pool), >= 1.
    backlog : int
        Queries that may wait for a thread, >= 0; beyond them a request gets 503.
    """

    concurrency: int = 16
    backlog: int = 64

    def __post_init__(self) -> None:
        for name, lo in (("concurrency", 1), ("backlog", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name}: must be an integer >= {lo}, got {v!r}")


class MeshPool:
    """Runs blocking mesh calls for the event loop, within :class:`MeshLimits`."""

    def __init__(self, limits: MeshLimits | None = None) -> None:
        self.limits = limits or MeshLimits()
        self._pool = ThreadPoolExecutor(max_workers=self.limits.concurrency,
                                        thread_name_prefix="ssmpc-mesh")
        self._lock = threading.Lock()
        self._admitted = 0  # under way or waiting, released when the call ends

    @property
    def admitted(self) -> int:
        with self._lock:
            return self._admitted

    def _release(self, _future) -> None:
        with self._lock:
            self._admitted -= 1

    async def run(self, fn, *args):
        """``await`` ``fn(*args)`` on the pool; :class:`MeshError` 503 when it is full."""
        limit = self.limits.concurrency + self.limits.backlog
        with self._lock:
            if self._admitted >= limit:
                raise MeshError(503, f"api busy: {limit} queries to the mesh under way or "
                                     "waiting; retry later")
            self._admitted += 1
        try:
            future = self._pool.submit(fn, *args)
        except BaseException:
            self._release(None)
            raise
        # released when the call really ends (not when a disconnected client cancels)
        future.add_done_callback(self._release)
        return await asyncio.wrap_future(future)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
