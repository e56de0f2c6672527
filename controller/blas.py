"""BLAS threads for the control loops: one thread, restored afterwards.

The loops do thousands of tiny matrix operations (4 x 4 to 400 x 400). On a shared
2-core machine a multi-threaded OpenBLAS makes each one wait for busy cores: an
H-infinity synthesis measured 130-250 ms with threads and 7-10 ms without.
"""

from __future__ import annotations

import contextlib
import ctypes

__all__ = ["single_threaded_blas"]


@contextlib.contextmanager
def single_threaded_blas():
    """Run with OpenBLAS limited to one thread (restored afterwards).

    These studies do thousands of tiny matrix operations (4 x 4 to 20 x 20). On the
    shared 2-core machine multi-threaded OpenBLAS makes each one wait for busy
    cores: an H-infinity synthesis measured 130-250 ms with threads and 7-10 ms
    without.
    """
    handles = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "blas" in ln.lower() and ".so" in ln})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for setter, getter in (("scipy_openblas_set_num_threads64_",
                                "scipy_openblas_get_num_threads64_"),
                               ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
                               ("openblas_set_num_threads", "openblas_get_num_threads")):
            if hasattr(lib, setter) and hasattr(lib, getter):
                set_fn, get_fn = getattr(lib, setter), getattr(lib, getter)
                handles.append((set_fn, int(get_fn())))
                set_fn(1)
                break
    try:
        yield
    finally:
        for set_fn, n in handles:
            set_fn(n)
