"""BLAS threads for the control loops: one thread while a loop runs, restored afterwards.

The loops do thousands of tiny matrix operations (4 x 4 to 400 x 400 per sample). A
multi-threaded OpenBLAS makes each one wait for busy cores: on the shared 2-core
machine an H-infinity synthesis measured 130-250 ms with threads and 7-10 ms without,
and a 48 h TE loop ran at 3.1-3.6 process-h/s instead of 11.3-13.8. So every closed
loop of the library runs with BLAS limited to one thread (:func:`single_threaded`):
the offline runners (:func:`controller.loop.run_closed_loop`,
:func:`controller.units.te.control.run_te`,
:func:`controller.units.two_phase_reactor.run_reactor`) and the nodes' ``run``.

The limit is OpenBLAS's own process-wide setter (``openblas_set_num_threads`` and its
``scipy_openblas`` variants), found through threadpoolctl's inventory of the loaded
libraries. threadpoolctl's ``threadpool_limits`` itself is documented for the main
thread only (joblib/threadpoolctl #205, #209) and measured here to leave OpenBLAS at
two threads when entered from a node's run thread, so it is not used to set the limit.
The limit is reference-counted: the first runner to enter sets one thread, the last to
leave restores the caller's counts (a plant and a controller node in one process).
Entering costs about 1.6 ms (the inventory), so it wraps a whole run, never a sample.

Measured limit: limited at run time, OpenBLAS still gives last-bit differences from run
to run (a 48 h TE run of the ``ssmpc`` strategy: 4 different move hashes in 5 runs),
while a process started with ``OPENBLAS_NUM_THREADS=1`` is bit-identical run after run.
The ``ssmpc`` command sets that variable before numpy loads; a Python program that
needs bit-identical reruns sets it itself.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import threading
from collections.abc import Callable, Iterator
from typing import TypeVar

__all__ = ["blas_threads", "single_threaded", "single_threaded_blas"]

F = TypeVar("F", bound=Callable)


_SETTERS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
            ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
            ("openblas_set_num_threads", "openblas_get_num_threads"))
_lock = threading.Lock()
_depth = 0
_saved: list[tuple] = []


#: Packages of the control loops that bring their own OpenBLAS, loaded lazily: each is
#: imported before the inventory, or its library would join later with its default
#: thread count (seen: slycot's, loaded by python-control mid-run, made a TE run's
#: moves differ from run to run).
_BLAS_USERS = ("numpy", "scipy.linalg", "slycot")


def _openblas_handles() -> list[tuple]:
    """``(set, get)`` of every OpenBLAS loaded in the process (the control loops'
    packages loaded first, :data:`_BLAS_USERS`)."""
    import importlib

    from threadpoolctl import threadpool_info

    for name in _BLAS_USERS:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)

    handles = []
    for info in threadpool_info():
        if info.get("internal_api") != "openblas":
            continue
        try:
            lib = ctypes.CDLL(info["filepath"])
        except OSError:
            continue
        for setter, getter in _SETTERS:
            if hasattr(lib, setter) and hasattr(lib, getter):
                handles.append((getattr(lib, setter), getattr(lib, getter)))
                break
    return handles


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """BLAS limited to one thread inside the block, from any thread; the caller's
    counts are restored when the last block open in the process ends."""
    global _depth, _saved
    with _lock:
        if _depth == 0:
            _saved = [(set_fn, int(get_fn())) for set_fn, get_fn in _openblas_handles()]
            for set_fn, _ in _saved:
                set_fn(1)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                for set_fn, n in _saved:
                    set_fn(n)
                _saved = []


def single_threaded(fn: F) -> F:
    """Decorator: ``fn`` runs with :func:`single_threaded_blas`."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with single_threaded_blas():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def blas_threads() -> int:
    """The largest thread count of the BLAS libraries loaded (0 if none is loaded)."""
    from threadpoolctl import threadpool_info

    return max((int(i.get("num_threads", 0)) for i in threadpool_info()
                if i.get("user_api") == "blas"), default=0)
