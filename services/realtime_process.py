"""The process settings a sample loop runs under, made once after set-up.

A node (plant, controller) and the benchmark that times the controller's sample run
their samples under the same settings, made by :func:`settle_for_samples` once every
model, kernel and connection exists and before the first sample:

* the cyclic garbage collector: what set-up made (modules, models, compiled kernels,
  ~196,000 tracked objects in a TE controller) is collected once and frozen
  (``gc.freeze``: the permanent generation, never traversed again) and the young
  generation collects after 50,000 net allocations instead of 700. A sample allocates
  a few tracked objects net, so a collection then falls into a sample rarely and
  traverses only what samples made;
* BLAS on the calling thread only (``threadpoolctl``): the sample's matrices are small
  (TE: 208 adapted parameters at most) and OpenBLAS's worker threads spin-wait
  between calls, which at 10,000x kept one of two vCPUs busy, away from the plant and
  Zenoh, and in a single process slow the sample thread they share the cores with;
* the interpreter's thread switch interval 0.5 ms instead of 5 ms, so the Zenoh
  callback threads and the sample loop hand the interpreter lock on sooner.

**Measured** (``ssmpc bench mpc-step``, the two-phase reactor's 600 samples with the
collector as Python leaves it, shared 2-core AMD EPYC): 3 of 600 samples held a
collection, 3 ms each (9 ms in all); with these settings none did. Full collections of
the unfrozen TE controller heap took 143-262 ms (then never, as nothing is left to
traverse). The TE controller node over 60 s rungs at 1,800x and 3,600x: no collection
at all in 9,000 samples (``controller_gc_pauses`` of ``ssmpc bench loop``).
"""

from __future__ import annotations

import gc
import math
import sys
from dataclasses import dataclass

__all__ = ["SampleProcessSettings", "settle_for_samples"]


@dataclass(frozen=True)
class SampleProcessSettings:
    """How :func:`settle_for_samples` sets the process up.

    Parameters
    ----------
    gc_thresholds : tuple of 3 int
        ``gc.set_threshold`` after the freeze: net allocations before a young
        collection, then young (resp. middle) collections before the next older one.
    switch_interval_s : float
        ``sys.setswitchinterval``, s: how long a thread may hold the interpreter lock
        while another waits for it.
    blas_threads : int
        BLAS threads (1: the calling thread only).
    """

    gc_thresholds: tuple[int, int, int] = (50_000, 50, 100)
    switch_interval_s: float = 0.0005
    blas_threads: int = 1

    def __post_init__(self) -> None:
        t = self.gc_thresholds
        if (not isinstance(t, tuple) or len(t) != 3
                or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in t)):
            raise ValueError(f"gc_thresholds: expected three integers >= 1, got {t!r}")
        s = self.switch_interval_s
        if isinstance(s, bool) or not isinstance(s, int | float) or not (
                math.isfinite(s) and s > 0):
            raise ValueError(f"switch_interval_s: must be a positive number of seconds, "
                             f"got {s!r}")
        b = self.blas_threads
        if isinstance(b, bool) or not isinstance(b, int) or b < 1:
            raise ValueError(f"blas_threads: must be an integer >= 1, got {b!r}")


def settle_for_samples(settings: SampleProcessSettings | None = None) -> dict:
    """Make the process settings of a sample loop (see the module docstring).

    Call once, after set-up and before the first sample. The collector's pauses are
    counted from now on (:data:`services.timing.GC_PAUSES`).

    Returns
    -------
    dict
        What was set: ``frozen`` (objects moved to the permanent generation),
        ``gc_thresholds``, ``switch_interval_s``, ``blas_threads``.
    """
    from threadpoolctl import threadpool_limits

    from services.timing import GC_PAUSES

    s = SampleProcessSettings() if settings is None else settings
    threadpool_limits(limits=s.blas_threads, user_api="blas")
    GC_PAUSES.install()
    gc.collect()
    gc.freeze()
    gc.set_threshold(*s.gc_thresholds)
    sys.setswitchinterval(s.switch_interval_s)
    return {"frozen": gc.get_freeze_count(), "gc_thresholds": list(s.gc_thresholds),
            "switch_interval_s": s.switch_interval_s, "blas_threads": s.blas_threads}
