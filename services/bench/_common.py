"""Benchmark result records for ``ssmpc bench``: median / p99 / max over samples.

A bench module returns a list of case dicts built with :func:`latency_case` or
:func:`rate_case`; :func:`bench_document` wraps them with the bench name and the
machine. Numbers are measured, never asserted in tests.
"""

from __future__ import annotations

import numpy as np

from services.machine import machine_description

__all__ = ["latency_case", "rate_case", "bench_document"]


def _summary(case: str, samples, unit: str, tail_percentile: float, extra: dict) -> dict:
    a = np.asarray(samples, dtype=float)
    if a.size == 0:
        raise ValueError(f"bench case {case!r}: no samples")
    out = {
        "case": case,
        "unit": unit,
        "median": float(np.median(a)),
        "p99": float(np.percentile(a, tail_percentile)),
        "max": float(a.max()),
        "n": int(a.size),
    }
    out.update(extra)
    return out


def latency_case(case: str, samples, unit: str = "us", **extra) -> dict:
    """Summarize per-call times. ``samples`` in ``unit`` (e.g. µs)."""
    return _summary(case, samples, unit, 99, extra)


def rate_case(case: str, rates, unit: str, **extra) -> dict:
    """Summarize a rate (e.g. simulated hours per wall second): ``median`` is the rate.

    ``p99`` is the 1st percentile of the rates (the slow tail), ``max`` the best run.
    """
    return _summary(case, rates, unit, 1, extra)


def bench_document(name: str, cases: list[dict], **extra) -> dict:
    doc = {"bench": name, "machine": machine_description(), "cases": cases}
    doc.update(extra)
    return doc
