"""``ssmpc bench qp``: the MPC QP backends side by side on a recorded closed-loop sequence.

The sequence is a TE-size Δu MPC (7 MVs, 5 CVs, P = 10, M = 4: 28 moves + 1 slack)
closing the loop on a synthetic stable plant of order 20 with model mismatch, moving
references and active input, rate and soft output limits. It is regenerated
deterministically from ``--seed`` (no files, no network), recorded once, and every
backend then solves exactly the same QPs in the same order, as the controller would
(one workspace, vectors updated per sample).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from controller.mpc.formulation import QPVectors, build_formulation
from controller.mpc.qp import DAQPBackend, ProxsuiteBackend
from controller.mpc.settings import MPCSettings

NAME = "qp"
DESCRIPTION = "MPC QP solve time per backend on a recorded TE-size closed-loop sequence"

TE_NU, TE_NY, TE_N, TE_P, TE_M = 7, 5, 20, 10, 4


@dataclass(frozen=True)
class QPSequence:
    """A recorded QP sequence with fixed (H, A)."""

    H: np.ndarray
    A: np.ndarray
    vectors: tuple[QPVectors, ...]
    settings: MPCSettings

    @property
    def nz(self) -> int:
        return self.H.shape[0]

    @property
    def n_rows(self) -> int:
        """Rows counted as the solvers see them: simple bounds plus general rows."""
        return self.H.shape[0] + self.A.shape[0]


def random_stable_model(rng: np.random.Generator, n: int, nu: int, ny: int,
                        radius=(0.6, 0.97)):
    """A stable discrete model (Φ, Γ, C) with real poles in ``radius``."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    Phi = Q @ np.diag(rng.uniform(*radius, size=n)) @ Q.T
    Gamma = rng.normal(size=(n, nu)) * 0.3
    C = rng.normal(size=(ny, n))
    return Phi, Gamma, C


def te_settings(backend: str = "daqp", **over) -> MPCSettings:
    kw = dict(nu=TE_NU, ny=TE_NY, P=TE_P, M=TE_M, Xi=[3.0, 1.0, 10.0, 1.0, 2.0],
              Lambda=np.full(TE_NU, 0.5), u_min=np.full(TE_NU, -1.5),
              u_max=np.full(TE_NU, 1.5), du_max=np.full(TE_NU, 0.25),
              y_min=np.full(TE_NY, -2.0), y_max=np.full(TE_NY, 2.0), slack_linear=1e3,
              slack_quadratic=10.0, backend=backend)
    kw.update(over)
    return MPCSettings(**kw)


def record_te_sequence(seed: int = 0, n_samples: int = 400) -> QPSequence:
    """Run the TE-size closed loop with DAQP (cold) and record every QP it solves."""
    rng = np.random.default_rng(seed)
    Phi, Gamma, C = random_stable_model(rng, TE_N, TE_NU, TE_NY)
    # Plant: the model with gain and pole mismatch.
    Phi_p = Phi * 1.01
    if np.max(np.abs(np.linalg.eigvals(Phi_p))) >= 0.995:
        Phi_p = Phi
    Gamma_p = Gamma * rng.uniform(0.8, 1.2, size=(1, TE_NU))
    s = te_settings()
    form = build_formulation(Phi, Gamma, C, s)
    solver = DAQPBackend(form.H, form.A, max_iter=s.max_iter, warm_start=False)
    x_p = np.zeros(TE_N)
    x_m = np.zeros(TE_N)
    x_m_prev = np.zeros(TE_N)
    u = np.zeros(TE_NU)
    d = np.zeros(TE_NY)
    sp = np.zeros(TE_NY)
    vectors = []
    beta = np.exp(-1.0 / 5.0)  # first-order reference, time constant 5 samples
    for k in range(n_samples):
        if k % 40 == 0:
            sp = rng.uniform(-2.6, 2.6, size=TE_NY)  # some beyond the soft limits
        if k % 25 == 10:
            d = d + rng.normal(size=TE_NY) * 0.3
        y = C @ x_p + d + rng.normal(size=TE_NY) * 0.01
        ref = sp + np.outer(beta ** np.arange(1, TE_P + 1), y - sp)
        x_a = np.concatenate([x_m - x_m_prev, y])
        v = form.qp_vectors(x_a, u, ref)
        vectors.append(v)
        res = solver.solve(v)
        du = res.x[:TE_NU] if res.ok else np.zeros(TE_NU)
        u = np.clip(u + du, s.u_min, s.u_max)
        x_p = Phi_p @ x_p + Gamma_p @ u
        x_m_prev, x_m = x_m, Phi @ x_m + Gamma @ u
    return QPSequence(H=np.array(form.H), A=np.array(form.A), vectors=tuple(vectors),
                      settings=s)


def solve_sequence(seq: QPSequence, backend: str, *, warm: bool,
                   unsafe_warm_start: bool = False, max_iter: int = 1000):
    """Solve every QP of ``seq`` in order with one workspace; returns the results."""
    if backend == "daqp":
        solver = DAQPBackend(seq.H, seq.A, max_iter=max_iter, warm_start=warm)
    else:
        solver = ProxsuiteBackend(seq.H, seq.A, max_iter=max_iter, warm_start=warm,
                                  unsafe_warm_start=unsafe_warm_start)
    return [solver.solve(v) for v in seq.vectors]


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=400, help="QPs in the sequence")
    parser.add_argument("--repeat", type=int, default=2, help="passes over the sequence")
    parser.add_argument("--seed", type=int, default=0, help="sequence seed")


def run(args) -> list[dict]:
    from services.bench._common import latency_case

    n = getattr(args, "samples", 400)
    repeat = getattr(args, "repeat", 3)
    if n < 1 or repeat < 1:
        raise ValueError("samples/repeat: must be >= 1")
    seq = record_te_sequence(getattr(args, "seed", 0), n)
    ref = solve_sequence(seq, "daqp", warm=False)
    cases = []
    for name, backend, warm, unsafe, eps in (
            ("daqp", "daqp", True, False, None),
            ("daqp cold", "daqp", False, False, None),
            ("proxsuite", "proxsuite", False, False, 1e-8),
            ("proxsuite eps 1e-5", "proxsuite", False, False, 1e-5),
            ("proxsuite warm (unsafe)", "proxsuite", True, True, 1e-8)):
        times, fails, worst = [], 0, 0.0
        for _ in range(repeat):
            results = [r for _, r in _timed(seq, backend, warm, times, unsafe, eps)]
            for r, r0 in zip(results, ref):
                if not r.ok:
                    fails += 1
                elif r0.ok:
                    worst = max(worst, float(np.max(np.abs(r.x - r0.x))))
        cases.append(latency_case(
            name, times, unit="us", backend=backend, warm_start=warm,
            default=(backend == "daqp" and warm), eps_abs=eps,
            variables=seq.nz, general_rows=int(seq.A.shape[0]),
            rows_with_bounds=seq.n_rows, qps=len(seq.vectors), failures=fails,
            max_abs_diff_vs_daqp_cold=worst))
    return cases


# The controller's default backend is DAQP (MPCSettings.backend): on this sequence it is
# ~100x faster than proxsuite at the median and at p99, gives the same solutions, and
# its warm start is exact; proxsuite's warm start reports feasible QPs infeasible.


def _timed(seq: QPSequence, backend: str, warm: bool, times: list, unsafe: bool = False,
           eps: float | None = None):
    if backend == "daqp":
        solver = DAQPBackend(seq.H, seq.A, warm_start=warm)
    else:
        solver = ProxsuiteBackend(seq.H, seq.A, warm_start=warm, unsafe_warm_start=unsafe,
                                  eps_abs=eps if eps is not None else 1e-8)
    for v in seq.vectors:
        t0 = time.perf_counter()
        r = solver.solve(v)
        times.append((time.perf_counter() - t0) * 1e6)
        yield v, r
