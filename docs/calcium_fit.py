"""Reconstruction of the Tang-Othmer CICR flux parameters from the seed's printed numbers.

Run from the repository root:  python docs/calcium_fit.py [--fit]

Without --fit it evaluates the frozen parameters of plant_sim/calcium.py and prints the
residual of every target (the table of docs/calcium_reconstruction.md). With --fit it
repeats the least-squares fit from the analytic starting point and prints the fitted
parameters to paste into plant_sim.calcium.PARAMETERS.
"""

from __future__ import annotations

import sys

import numpy as np
import scipy.linalg as sl
from scipy.optimize import least_squares

from plant_sim.calcium import OP_CYTOSOL_CA, PARAMETERS, Calcium
from plant_sim.linearize import linearize

# ---- printed targets (seed ch. 3 and 6; facts/two_phase_reactor_calcium.md §2.5-2.6) ----
X6_PRINTED = {"OPI": 38.6162, "OPII": 39.262}
EIG_CH3 = {"OPI": (-841.32, -1.6876, 2.4192, -0.8245),       # 4th-order minimal model
           "OPII": (-685.37, -1.0749, 2.5178, -0.7834)}
RED_A = {
    "OPI": [[-2.7566, 2.8145, -0.4583], [-2.8152, -0.6653, 1.0459],
            [-0.4589, -1.0459, -0.1260]],
    "OPII": [[-1.0898, -2.9738, 0.6683], [2.9905, -0.0010, 0.0192],
             [0.6684, -0.0292, -0.7040]],
}
RED_B = {  # printed column order is (q1, J)
    "OPI": [[1.6977, -2.0232], [0.5244, -0.6249], [0.1736, -0.2069]],
    "OPII": [[1.5888, -1.7938], [-0.0480, 0.0542], [-0.5919, 0.6683]],
}
RED_C_OPI = [[-0.0289, 0.0372, -0.0137], [-2.6409, 0.8149, -0.2697]]
POLE_ZERO = -10.605


def printed_facts():
    """Quantities derived from the printed reduced models (independent of our model)."""
    out = {}
    for op in ("OPI", "OPII"):
        A, B = np.array(RED_A[op]), np.array(RED_B[op])
        Wc = sl.solve_continuous_lyapunov(A, -B @ B.T)
        ev = np.linalg.eigvals(A)
        c = ev[np.argmax(ev.imag)]
        r = ev[np.argmin(abs(ev.imag))]
        out[op] = {"hsv": np.diag(Wc).copy(),           # balanced: gramian diagonal = HSV
                   "red_eig": (c.real, abs(c.imag), r.real),
                   "ratio_J_over_q1": float(np.mean(B[:, 1] / B[:, 0]))}
    A, B, C = (np.array(M) for M in (RED_A["OPI"], RED_B["OPI"], RED_C_OPI))
    out["OPI"]["dc"] = C @ np.linalg.solve(-A, B)       # columns (q1, J)
    return out


def q2_and_leak(pf):
    """q2 from the two B-column ratios (J coefficient 1), J_lm from the OPI DC gain x5/J."""
    x_i, x_ii = OP_CYTOSOL_CA["OPI"], OP_CYTOSOL_CA["OPII"]
    # |q1 column / J column| = h(x5) = x5^2 / (x5^2 + q2^2)
    q2s = [x * np.sqrt(1 / (-1 / pf[op]["ratio_J_over_q1"]) - 1)
           for op, x in (("OPI", x_i), ("OPII", x_ii))]
    q2 = float(np.mean(q2s))
    dh = 2 * x_i * q2**2 / (x_i**2 + q2**2) ** 2
    q1_opi = (1 / pf["OPI"]["dc"][0, 1]) / dh          # x5/J = 1 / J_pm'(x5)
    return q2, q1_opi * x_i**2 / (x_i**2 + q2**2), q2s


def balanced_truncation(A, B, C, k):
    """Square-root balanced truncation (works for non-minimal stable systems)."""
    Wc = sl.solve_continuous_lyapunov(A, -B @ B.T)
    Wo = sl.solve_continuous_lyapunov(A.T, -C.T @ C)
    s, U = np.linalg.eigh((Wc + Wc.T) / 2)
    Lc = U * np.sqrt(np.clip(s, 0, None))
    s, U = np.linalg.eigh((Wo + Wo.T) / 2)
    Lo = U * np.sqrt(np.clip(s, 0, None))
    W, S, Vt = np.linalg.svd(Lo.T @ Lc)
    T = Lc @ Vt.T[:, :k] / np.sqrt(S[:k])
    Ti = (W[:, :k] / np.sqrt(S[:k])).T @ Lo.T
    return Ti @ A @ T, Ti @ B, C @ T, S


def evaluate(plant: Calcium) -> dict:
    """Everything the targets compare against, at both operating points."""
    out = {}
    for op in ("OPI", "OPII"):
        lm = linearize(plant, op).select(inputs=["q1", "J"], outputs=["x5", "x6"])
        x5 = lm.x_op[3]
        unc = -(plant.p["km1"] + plant.p["km2"] + (plant.p["k1"] + plant.p["k2"]) * x5)
        ev = np.linalg.eigvals(lm.A)
        k = int(np.argmin(abs(ev - unc)))
        unc_found = ev[k]
        ev = np.delete(ev, k)
        fast = ev[np.argmin(ev.real)]
        rest = ev[ev.real > fast.real]
        cc = rest[np.argmax(rest.imag)]
        rr = rest[np.argmin(abs(rest.imag))]
        Ar, Br, Cr, S = balanced_truncation(lm.A, lm.B, lm.C, 3)
        er = np.linalg.eigvals(Ar)
        c = er[np.argmax(er.imag)]
        r = er[np.argmin(abs(er.imag))]
        out[op] = {
            "x6": lm.x_op[4], "q1": lm.u_op[0], "uncontrollable": unc_found.real,
            "eig": (fast.real, cc.real, abs(cc.imag), rr.real),
            "red_eig": (c.real, abs(c.imag), r.real), "hsv": S[:4],
            "dc": Cr @ np.linalg.solve(-Ar, Br),
            "ratio_J_over_q1": lm.B[3, 1] / lm.B[3, 0],
            "rank_B": int(np.linalg.matrix_rank(lm.B, tol=1e-9 * np.abs(lm.B).max())),
        }
    return out


def residuals(plant: Calcium, pf: dict, w_sr: float = 10.0) -> np.ndarray:
    ev = evaluate(plant)
    r = []
    for op in ("OPI", "OPII"):
        e, t = ev[op], EIG_CH3[op]
        r.append((e["eig"][0] - t[0]) / abs(t[0]))
        r.append((e["eig"][3] - t[3]) / abs(t[3]))
        r += [(g - v) / abs(v) for g, v in zip(e["red_eig"], pf[op]["red_eig"])]
        r += [(e["hsv"][i] - pf[op]["hsv"][i]) / pf[op]["hsv"][i] for i in range(3)]
        r.append(w_sr * (e["x6"] - X6_PRINTED[op]) / X6_PRINTED[op])
    dc, dcp = ev["OPI"]["dc"], pf["OPI"]["dc"]
    r += [(dc[0, 1] - dcp[0, 1]) / dcp[0, 1], (dc[1, 1] - dcp[1, 1]) / dcp[1, 1]]
    return np.array(r)


FITTED = ("vr", "gamma0", "gamma1", "p1", "p2", "J_lm")


def fit(pf) -> dict:
    q2, j_lm, _ = q2_and_leak(pf)
    # analytic start (doc §3): vr from the total-Ca identity, J_lm from the printed DC
    # gain x5/J, the rest from OPI's trace, DC ratio and G6 zeros.
    z0 = np.log([0.185, 2.44, 88.15, 1205.9, 0.1101, j_lm])

    def fun(z):
        params = dict(zip(FITTED, np.exp(z), strict=True), q2=q2)
        return residuals(Calcium(outputs=("x5", "x6"), params=params), pf)

    # two passes: J_lm held at its DC value first, then everything together
    sol = least_squares(lambda z5: fun(np.append(z5, np.log(j_lm))), z0[:5], method="lm",
                        max_nfev=4000)
    sol = least_squares(fun, np.append(sol.x, np.log(j_lm)), method="lm", max_nfev=4000)
    return dict(zip(FITTED, np.exp(sol.x), strict=True), q2=q2)


def report(plant: Calcium, pf: dict) -> None:
    ev = evaluate(plant)
    q2, j_lm, q2s = q2_and_leak(pf)
    print(f"q2 from the OPI / OPII B ratios: {q2s[0]:.5f} / {q2s[1]:.5f} uM; J_lm from the "
          f"printed DC gain {j_lm:.6f} (fitted {plant.p['J_lm']:.6f}) uM/s")

    def row(name, ours, seed):
        err = 100 * (ours - seed) / abs(seed) if seed else float("nan")
        print(f"  {name:<34} ours {ours:>11.5g}   seed {seed:>11.5g}   {err:+7.2f} %")

    for op in ("OPI", "OPII"):
        e, t = ev[op], EIG_CH3[op]
        print(f"{op}: x5 = {OP_CYTOSOL_CA[op]} uM, q1 = {e['q1']:.5f} uM/s, rank B = "
              f"{e['rank_B']}")
        row("x6 (uM)", e["x6"], X6_PRINTED[op])
        row("uncontrollable pole/zero", e["uncontrollable"], POLE_ZERO)
        for name, g, v in zip(("fast eigenvalue (ch.3)", "complex pair real (ch.3)",
                               "complex pair imag (ch.3)", "slow eigenvalue (ch.3)"),
                              e["eig"], t):
            row(name, g, v)
        for name, g, v in zip(("reduced pair real (ch.6)", "reduced pair imag (ch.6)",
                               "reduced real pole (ch.6)"), e["red_eig"], pf[op]["red_eig"]):
            row(name, g, v)
        for i in range(3):
            row(f"Hankel singular value {i + 1} (ch.6)", e["hsv"][i], pf[op]["hsv"][i])
        row("B ratio J/q1", e["ratio_J_over_q1"], pf[op]["ratio_J_over_q1"])
        print(f"  4th Hankel singular value {e['hsv'][3]:.4g}; "
              f"Re order 3 = {e['hsv'][3] / np.linalg.norm(e['hsv']):.4%}")
    dc, dcp = ev["OPI"]["dc"], pf["OPI"]["dc"]
    for (i, j), name in (((0, 1), "x5/J"), ((1, 1), "x6/J"), ((0, 0), "x5/q1"),
                         ((1, 0), "x6/q1")):
        row(f"OPI DC gain {name} (order 3)", dc[i, j], dcp[i, j])


if __name__ == "__main__":
    pf = printed_facts()
    if "--fit" in sys.argv:
        params = fit(pf)
        for k, v in params.items():
            print(f'    "{k}": {v!r},')
        plant = Calcium(outputs=("x5", "x6"), params=params)
    else:
        plant = Calcium(outputs=("x5", "x6"))
        print("frozen PARAMETERS:", {k: PARAMETERS[k] for k in (*FITTED, "q2")})
    report(plant, pf)
