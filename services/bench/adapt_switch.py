"""``ssmpc bench adapt-switch``: per-sample cost of shared-state update + adapt + switch.

One sample of :class:`controller.multimodel.MultiModelController` without its control
law: a-priori model errors, normalized least squares (eq. 4.1) for every adaptive
model on the shared regressor, the performance index (eq. 4.6), switching with the
re-initialization event, and the shared-state update.

Cases:

- ``siso-4-models``: the seed's chapter-5 set (n = 2, m = 1: M1, M2 fixed, M3
  free-running, M4 re-initialized), 5 parameters per model.
- ``te``: the TE size of R7.15 (n = 40, m = 5: three fixed models and one
  re-initialized adaptive model), 1040 + 5 parameters, full covariance (1045 x 1045).

Signals are a deterministic random walk (seeded); timings in microseconds.
"""

from __future__ import annotations

import time

import numpy as np

from controller.adaptation import NLSSettings
from controller.multimodel import HoldLaw, MultiModelController, MultiModelSettings
from controller.state_shared import ModelSpec, StateSharedModel
from controller.switching import IndexSettings
from services.bench._common import latency_case

NAME = "adapt-switch"
DESCRIPTION = "per-sample cost of shared-state update + adaptation + switching (SISO, TE size)"


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=2000,
                        help="samples timed for the SISO case (TE uses a tenth, at least 50)")
    parser.add_argument("--blas", choices=("single", "default"), default="single",
                        help="OpenBLAS threads: one (default; small matrices) or the library's")
    parser.add_argument("--case", choices=("all", "siso-4-models", "te"), default="all")


def _controller(n: int, m: int, kinds: list[str], rng) -> MultiModelController:
    a = np.poly(-np.linspace(0.5, 1.5, n))[1:][::-1]  # Hurwitz, lowest power first
    ssm = StateSharedModel(a, m, 0.1)
    for j, kind in enumerate(kinds):
        theta = np.zeros((2 * n * m, m))
        theta[: n * m] = 0.01 * rng.standard_normal((n * m, m))
        t2 = 0.01 * rng.standard_normal(n)
        for i in range(m):
            theta[n * m + i * n : n * m + (i + 1) * n, i] = t2
        ssm.add_model(ModelSpec(f"M{j + 1}", theta, np.zeros(m),
                                "fixed" if kind == "fixed" else "adaptive"))
    settings = MultiModelSettings(NLSSettings(kappa=10.0, gain=3.0, rate=1.0),
                                  IndexSettings(1.0, 0.1, 0.5, 0.5))
    return MultiModelController(ssm, HoldLaw(), np.zeros(m), settings, kinds=kinds)


def _time(ctl: MultiModelController, m: int, n_samples: int, rng) -> np.ndarray:
    y = np.zeros(m)
    ref = np.zeros((1, m))
    for k in range(20):  # warm-up: initialization and first allocations
        y = y + 0.05 * rng.standard_normal(m)
        ctl.step(k, 0.1 * k, y, ref)
    times = np.empty(n_samples)
    for k in range(n_samples):
        y = y + 0.05 * rng.standard_normal(m)
        ctl.u_last = ctl.u_last + 0.05 * rng.standard_normal(m)
        t0 = time.perf_counter()
        ctl.step(k, 0.1 * k, y, ref)
        times[k] = (time.perf_counter() - t0) * 1e6
    return times


def run(args) -> list[dict]:
    import contextlib

    from controller.blas import single_threaded_blas

    if args.samples < 10:
        raise ValueError(f"samples: must be >= 10, got {args.samples}")
    ctx = single_threaded_blas() if args.blas == "single" else contextlib.nullcontext()
    cases = []
    with ctx:
        if args.case in ("all", "siso-4-models"):
            rng = np.random.default_rng(0)
            ctl = _controller(2, 1, ["fixed", "fixed", "free-running", "re-initialized"], rng)
            t = _time(ctl, 1, args.samples, rng)
            cases.append(latency_case("siso-4-models", t, n_params=ctl.ssm.n_params + 1,
                                      models=4, adaptive=2, blas=args.blas))
        if args.case in ("all", "te"):
            rng = np.random.default_rng(1)
            ctl = _controller(40, 5, ["fixed", "fixed", "fixed", "re-initialized"], rng)
            t = _time(ctl, 5, max(50, args.samples // 10), rng)
            cases.append(latency_case("te", t, n_params=ctl.ssm.n_params + 5, models=4,
                                      adaptive=1, blas=args.blas))
    return cases
