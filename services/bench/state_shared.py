"""``ssmpc bench state-shared``: one sample of the state-shared model.

Each measured call is ``update(u, y)`` followed by ``estimates()`` (all models'
outputs), the per-sample work of the identifier before adaptation and
switching. Sizes: TE as in the seed (n = 40, m = 5, order 400, 3 fixed + 1 adaptive
model, R7.15), two-phase reactor (n = 2, m = 3), SISO (n = 2, m = 1); with
``--te-model`` also the numerically sane TE model actually built
(:mod:`controller.units.te.linear_models`, n = 8). Thetas are
random: the cost does not depend on their values. Also reported: building one
model's prediction form (exact ZOH of the 400-state closed form) at TE size.
"""

from __future__ import annotations

import time

import numpy as np

from controller.state_shared import ModelSpec, StateSharedModel, designer_polynomial
from services.bench._common import latency_case

NAME = "state-shared"
DESCRIPTION = "state-shared model: one update + all model estimates (TE size, SISO), in us"

SIZES = {  # case -> (n, m, models)
    "te_n40_m5_k4": (40, 5, 4),
    "two_phase_n2_m3_k4": (2, 3, 4),
    "siso_n2_m1_k4": (2, 1, 4),
}


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=20000, help="timed calls per case")
    parser.add_argument("--seed", type=int, default=0, help="random seed for thetas and signals")
    parser.add_argument("--te-model", action="store_true",
                        help="also time the real TE model (n = 8, modes 0/2/3 + adaptive; "
                             "builds TE linearizations first, ~10 s)")


def build(n: int, m: int, k: int, rng: np.random.Generator, dt: float = 0.01) -> StateSharedModel:
    """A state-shared model of the given size with random thetas (first k-1 fixed)."""
    # roots spread over a decade: a Hurwitz degree-n polynomial without repeated roots
    a = designer_polynomial(-np.geomspace(0.5, 5.0, n))
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
    for case, (n, m, k) in SIZES.items():
        ssm = build(n, m, k, rng)
        cases.append(latency_case(f"update+estimates {case}", _time_sample(ssm, args.samples, rng),
                                  "us", n_deg=n, m=m, models=k, order=ssm.order))
    if getattr(args, "te_model", False):
        from controller.units.te.linear_models import te_state_shared_model

        ssm = te_state_shared_model(dt=0.01)
        cases.append(latency_case("update+estimates te_model_n8_m5_k4",
                                  _time_sample(ssm, args.samples, rng), "us", n_deg=ssm.n_deg,
                                  m=ssm.m, models=ssm.k, order=ssm.order))
    n, m, k = SIZES["te_n40_m5_k4"]
    ssm = build(n, m, k, rng)
    reps = max(3, min(20, args.samples // 1000))
    t = np.empty(reps)
    for i in range(reps):
        ssm.set_theta(0, ssm.theta(0))  # invalidates the cached prediction form
        t0 = time.perf_counter_ns()
        ssm.prediction_form(0)
        t[i] = (time.perf_counter_ns() - t0) / 1e3
    cases.append(latency_case("prediction_form te_n40_m5", t, "us", order=ssm.order))
    return cases
