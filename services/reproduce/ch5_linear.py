"""Seed chapter 5, the plants' steady states and linear models: R5.1, R5.2 and R5.9.

Every ``ours`` is computed from :mod:`plant_sim`: steady states from the plants'
steady-state maps, transfer functions from :func:`plant_sim.linearize.linearize`
(numerical Jacobians) converted with :func:`scipy.signal.ss2tf`.

- R5.1 (CSTR, seed §5.1.2, Fig. 5.2): the steady states at the jacket temperature of
  OPI and OPII, found as the roots of the steady-state map u(y) = u_op on a grid of
  y in [0, 10] (bracketed, refined by :func:`scipy.optimize.brentq`), each
  classified by the eigenvalues of our Jacobian.
- R5.2 (Table 5.3): G(s) = k1 (s + k2)/(s^2 + k3 s + k4) at y = 1.3, 5.0, 2.0.
  The CSTR parameters (Da 0.072, gamma 20, B 8, beta 0.3) are the standard
  Uppal-Ray-Poore set of the literature, not a fit to the table
  (docs/facts/cstr_bioreactor.md §3), so a match is ``reproduced``.
- R5.9 (Table 5.10): the bioreactor's kinetics are a reconstruction fitted to this
  table (x1 and mu(x2) = D at both points, both denominators;
  docs/facts/cstr_bioreactor.md §2.2), so a match is ``calibrated``.

Measured limits (this machine): k1 is 0.3 to 1e-13 and k2-k4 agree with the
closed-form values of docs/facts/cstr_bioreactor.md §3 to 1e-4 (finite-difference
Jacobians).
"""

from __future__ import annotations

import math

import numpy as np

from services.reproduce import ReproduceResult, Row, StudyContext

__all__ = ["RESULTS", "cstr_k", "steady_states_at"]

K_REL = 0.02  # R5.2 / R5.9 coefficients: within ±2 % (the catalogue's tolerance)
X_ABS = 5e-4  # R5.9 steady states: to 3 decimals
Y_GRID = np.linspace(0.0, 10.0, 4001)  # R5.1: dimensionless temperatures searched

#: Table 5.3, printed (k1, k2, k3, k4) at OPI (y = 1.3), OPII (5.0), OPIII (2.0).
TABLE_5_3 = {"OPI": (0.3000, 1.2440, 1.1605, 0.2337),
             "OPII": (0.3000, 4.9310, 2.1493, 2.3286),
             "OPIII": (0.3000, 1.4437, 0.7121, -0.1548)}
#: Printed stability types, as the number of eigenvalues in the right half-plane.
TYPES_5_3 = {"OPI": 0.0, "OPII": 0.0, "OPIII": 1.0}  # stable node, stable, saddle


def _tf(plant, op, x=None, u=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(numerator, denominator, eigenvalues) of the SISO linearization at ``op``."""
    from scipy.signal import ss2tf

    from plant_sim.linearize import linearize

    lm = linearize(plant, op) if x is None else linearize(plant, op, x=x, u=u)
    num, den = ss2tf(lm.A, lm.B, lm.C, lm.D)
    return np.asarray(num[0], dtype=float), np.asarray(den, dtype=float), \
        np.linalg.eigvals(lm.A)


def cstr_k(plant, op: str) -> tuple[float, float, float, float]:
    """Our linearization at ``op`` as the seed's (k1, k2, k3, k4)."""
    num, den, _ = _tf(plant, op)
    k1 = float(num[-2])
    return k1, float(num[-1] / k1), float(den[1] / den[0]), float(den[2] / den[0])


def steady_states_at(plant, u: float) -> list[tuple[float, int]]:
    """CSTR steady states with jacket temperature ``u``: ``[(y, n_rhp_eigenvalues)]``.

    Roots of u(y) - u on :data:`Y_GRID`, refined by brentq; a root at a grid node counts
    once.
    """
    from scipy.optimize import brentq

    from plant_sim.linearize import linearize

    def g(y):
        return plant.steady_input(y)[1] - u

    vals = np.array([g(y) for y in Y_GRID])
    roots = []
    for i in range(len(Y_GRID) - 1):
        if vals[i] == 0.0:
            roots.append(float(Y_GRID[i]))
        elif vals[i] * vals[i + 1] < 0:
            roots.append(float(brentq(g, Y_GRID[i], Y_GRID[i + 1], xtol=1e-12)))
    out = []
    for y in roots:
        x1, uu = plant.steady_input(y)
        lm = linearize(plant, "OPI", x=[x1, y], u=[uu])
        out.append((y, int(np.sum(np.linalg.eigvals(lm.A).real > 0))))
    return out


def r5_1(ctx: StudyContext) -> ReproduceResult:
    from plant_sim import get_plant

    plant = get_plant("cstr")
    rows, ok, notes = [], True, []
    for op in ("OPI", "OPII"):
        u = float(plant.operating_point(op).u[0])
        ss = steady_states_at(plant, u)
        n_stable = sum(1 for _, n in ss if n == 0)
        n_saddle = sum(1 for _, n in ss if n == 1)
        rows += [Row(f"{op} jacket temperature u (Table 5.2 lost)", "-", None, u),
                 Row(f"steady states at {op}'s u (Fig. 5.2: three)", "-", 3.0, float(len(ss))),
                 Row(f"stable steady states at {op}'s u (Fig. 5.2: two nodes)", "-", 2.0,
                     float(n_stable)),
                 Row(f"saddles at {op}'s u (Fig. 5.2: one)", "-", 1.0, float(n_saddle))]
        for i, (y, _) in enumerate(ss):
            rows.append(Row(f"steady state {i + 1} at {op}'s u: y", "-", None, y))
        ok &= len(ss) == 3 and n_stable == 2 and n_saddle == 1
        notes.append(f"{op} (u = {u:.4f}): y = " + ", ".join(f"{y:.3f}" for y, _ in ss))
    # The seed's OPI and OPII lie on the outer branches at (nearly) one u: each point's
    # three steady states include the other's neighbourhood.
    why = ("Steady states of our CSTR (plant_sim.cstr, the Uppal-Ray-Poore parameters) at "
           "the jacket temperature of each operating point, roots of the steady-state map "
           "over y in [0, 10], classified by our Jacobian: " + "; ".join(notes)
           + ". Check (exact): three steady states, two stable and one saddle, as Fig. 5.2 "
           "says for some u. Tables 5.1-5.2 are lost, so u and x1 have no printed number.")
    return ReproduceResult("R5.1", rows, "reproduced" if ok else "differs", why)


def r5_2(ctx: StudyContext) -> ReproduceResult:
    from plant_sim import get_plant

    plant = get_plant("cstr")
    rows, worst, types_ok = [], 0.0, True
    for op, printed in TABLE_5_3.items():
        ks = cstr_k(plant, op)
        for i, (s, o) in enumerate(zip(printed, ks)):
            rows.append(Row(f"{op} k{i + 1}", "-", s, o))
            worst = max(worst, abs(o - s) / abs(s))
        _, _, ev = _tf(plant, op)
        n_rhp = float(np.sum(ev.real > 0))
        rows.append(Row(f"{op} eigenvalues in the right half-plane (printed type)", "-",
                        TYPES_5_3[op], n_rhp))
        for j, e in enumerate(sorted(ev, key=lambda z: (z.real, z.imag))):
            rows.append(Row(f"{op} pole {j + 1}, real part", "-", None, float(e.real)))
        k1, k2, _, k4 = ks
        rows.append(Row(f"{op} DC gain k1 k2 / k4", "-", None,
                        k1 * k2 / k4 if k4 else math.inf))
        types_ok &= n_rhp == TYPES_5_3[op]
    ok = worst <= K_REL and types_ok
    why = (f"Linearizations of plant_sim.cstr at y = 1.3, 5.0, 2.0 as k1 (s + k2)/(s^2 + k3 s "
           f"+ k4): largest deviation from Table 5.3 {100 * worst:.3f} % (tolerance "
           f"{100 * K_REL:g} %), stability types {'as' if types_ok else 'NOT as'} printed "
           "(stable node, stable, saddle). The parameters are the literature's standard set, "
           "not fitted to the table.")
    return ReproduceResult("R5.2", rows, "reproduced" if ok else "differs", why)


#: Table 5.10 as printed (OPI's numerator is lost in OCR; OPI's x2 = 0.0003 is flagged).
TABLE_5_10 = {
    "OPI": {"x1": 0.6790, "x2": 0.0003, "num": (None, None), "den": (46.9331, 17.7229)},
    "OPII": {"x1": 0.2410, "x2": 0.3890, "num": (1.4110, 0.5654), "den": (0.9000, -0.1281)},
}
TYPES_5_10 = {"OPI": 0.0, "OPII": 1.0, "OPIII": 0.0}  # stable, saddle, stable (washout)


def r5_9(ctx: StudyContext) -> ReproduceResult:
    from plant_sim import get_plant

    plant = get_plant("bioreactor")
    rows, fails = [], []
    for op, printed in TABLE_5_10.items():
        x = plant.operating_point(op).x
        for i, name in enumerate(("x1", "x2")):
            rows.append(Row(f"{op} steady state {name}", "g/L", printed[name], float(x[i])))
            judged = not (op == "OPI" and name == "x2")  # the flagged 0.0003
            if judged and abs(x[i] - printed[name]) > X_ABS:
                fails.append(f"{op} {name}")
        num, den, _ = _tf(plant, op)
        for label, s, o in (("numerator s coefficient", printed["num"][0], num[-2]),
                            ("numerator constant", printed["num"][1], num[-1]),
                            ("denominator s coefficient", printed["den"][0], den[1] / den[0]),
                            ("denominator constant", printed["den"][1], den[2] / den[0])):
            rows.append(Row(f"{op} {label}", "-", s, float(o)))
            if s is not None and abs(o - s) > K_REL * abs(s):
                fails.append(f"{op} {label}")
    for op, n_printed in TYPES_5_10.items():
        _, _, ev = _tf(plant, op)
        n = float(np.sum(ev.real > 0))
        rows.append(Row(f"{op} eigenvalues in the right half-plane (printed type)", "-",
                        n_printed, n))
        if n != n_printed:
            fails.append(f"{op} type")
    tol = (f"tolerances: steady states {X_ABS:g} g/L, transfer-function coefficients "
           f"{100 * K_REL:g} %, stability types exact")
    excluded = ("OPI's printed x2 = 0.0003 is not judged: the printed OPI numerator needs x2 "
                "between 0.003 and 0.004 (docs/facts/cstr_bioreactor.md §2.3), ours is "
                f"{plant.operating_point('OPI').x[1]:.5f}")
    if fails:
        verdict = "differs"
        why = (f"outside the tolerance: {', '.join(fails)} ({tol}); {excluded}. The kinetics "
               "of plant_sim.bioreactor were fitted to this table")
    else:
        verdict = "calibrated"
        why = ("Steady states and linear models D -> x2 of plant_sim.bioreactor match Table "
               f"5.10 ({tol}), but its kinetics (Table 5.9 is lost) were fitted to this "
               "table: x1 and mu(x2) = D at both points and both denominators "
               "(docs/facts/cstr_bioreactor.md §2.2), so the match proves the fit. Not fitted: "
               "the OPII numerator (structure (x2f - x2)(s + D); its constant 0.5644 vs the "
               f"printed 0.5654) and the washout point's type. {excluded}.")
    return ReproduceResult("R5.9", rows, verdict, why)


RESULTS = {"R5.1": r5_1, "R5.2": r5_2, "R5.9": r5_9}
