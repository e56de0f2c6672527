"""``ssmpc bench state-shared``: one sample of the state-shared model.

Each measured call is ``update(u, y)`` followed by ``estimates()`` (all models'
outputs), the per-sample work of the identifier before adaptation and
switching. Sizes: TE as in the seed (n = 40, m = 5, order 400, 3 fixed + 1 adaptive
model, R7.15), two-phase reactor (n = 2, m = 3), SISO (n = 2, m = 1); with
``--te-model`` also the numerically sane TE model actually built
(:mod:`controller.units.te.linear_models`, n = 8). Thetas are
random: the cost does not depend on their values. Also reported: building one
model's prediction form (exact ZOH of the 400-state closed form) at TE size.

Cases at TE size are named by the shared state's basis (``companion``: the
seed's eq. 3.12-3.13; ``orthonormal``: :mod:`controller.shared_basis`) and carry
it in the field ``basis``; the per-sample work has the same shape in both (one
(m+p) x (n+1) by (n+1) x n product and one stacked read-out), so they should
time alike. ``--te-model`` adds the real TE models: n = 8 in the companion
basis and the seed's n = 40 in the orthonormal one.
"""

from __future__ import annotations

import time

import numpy as np

from controller.state_shared import ModelSpec, SharedBasis, StateSharedModel, designer_polynomial
from services.bench._common import latency_case

NAME = "state-shared"
DESCRIPTION = "state-shared model: one update + all model estimates (TE size, SISO), in us"

SIZES = {  # case -> (n, m, models, bases)
    "te_n40_m5_k4": (40, 5, 4, ("companion", "orthonormal")),
    "two_phase_n2_m3_k4": (2, 3, 4, ("companion",)),
    "siso_n2_m1_k4": (2, 1, 4, ("companion",)),
}


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=20000, help="timed calls per case")
    parser.add_argument("--seed", type=int, default=0, help="random seed for thetas and signals")
    parser.add_argument("--te-model", action="store_true",
                        help="also time the real TE models (n = 8 companion, n = 40 "
                             "orthonormal; modes 0/2/3 + adaptive; builds TE linearizations "
                             "first, ~20 s)")


def build(n: int, m: int, k: int, rng: np.random.Generator, dt: float = 0.01,
          basis: str = "companion") -> StateSharedModel:
    """A state-shared model of the given size with random thetas (first k-1 fixed)."""
    # roots spread over a decade: a Hurwitz degree-n polynomial without repeated roots
    roots = -np.geomspace(0.5, 5.0, n)
    a = designer_polynomial(roots) if basis == "companion" else SharedBasis.orthonormal(roots)
    ssm = StateSharedModel(a, m, dt)
    for j in range(k):
        kind = "adaptive" if j == k - 1 else "fixed"
        ssm.add_model(ModelSpec(f"M{j}", 1e-3 * rng.standard_normal((2 * n * m, m)),
                                rng.standard_normal(m), kind))
    return ssm


def _time_sample(ssm: StateSharedModel, samples: int, rng: np.random.Generator) -> np.ndarray:
    m = ssm.m
    us = rng.standard_normal((samples, m))
    ys = rng.standard_normal((samples, m))
    for i in range(min(200, samples)):  # warm-up
        ssm.update(us[i], ys[i])
        ssm.estimates()
    out = np.empty(samples)
    clock = time.perf_counter_ns
    for i in range(samples):
        t0 = clock()
        ssm.update(us[i], ys[i])
        ssm.estimates()
        out[i] = clock() - t0
    return out / 1e3


def run(args) -> list[dict]:
    if args.samples < 1:
        raise ValueError(f"samples: must be >= 1, got {args.samples}")
    rng = np.random.default_rng(args.seed)
    cases = []
    for case, (n, m, k, bases) in SIZES.items():
        for basis in bases:
            ssm = build(n, m, k, rng, basis=basis)
            name = f"update+estimates {case}" + (f" {basis}" if len(bases) > 1 else "")
            cases.append(latency_case(name, _time_sample(ssm, args.samples, rng), "us",
                                      n_deg=n, m=m, models=k, order=ssm.order, basis=basis))
    if getattr(args, "te_model", False):
        from controller.units.te.linear_models import te_state_shared_model

        for order, basis in ((8, "companion"), (40, "orthonormal")):
            ssm = te_state_shared_model(dt=0.01, order=order, basis=basis)
            cases.append(latency_case(f"update+estimates te_model_n{order}_m5_k4 {basis}",
                                      _time_sample(ssm, args.samples, rng), "us",
                                      n_deg=ssm.n_deg, m=ssm.m, models=ssm.k, order=ssm.order,
                                      basis=basis))
    n, m, k, bases = SIZES["te_n40_m5_k4"]
    reps = max(3, min(20, args.samples // 1000))
    for basis in bases:
        ssm = build(n, m, k, rng, basis=basis)
        t = np.empty(reps)
        for i in range(reps):
            ssm.set_theta(0, ssm.theta(0))  # invalidates the cached prediction form
            t0 = time.perf_counter_ns()
            ssm.prediction_form(0)
            t[i] = (time.perf_counter_ns() - t0) / 1e3
        cases.append(latency_case(f"prediction_form te_n40_m5 {basis}", t, "us",
                                  order=ssm.order, basis=basis))
    return cases
