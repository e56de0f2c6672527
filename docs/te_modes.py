"""Compute the back-off grades of TE modes 4-6 (``controller.units.te.max_production``).

For each maximum-production mode: closed-loop runs of the cascade (strategy ssmpc,
noise off, 36 h, the grade requested at 1 h from Ricker's minimum-cost optimum of
the same G/H ratio) toward points of the back-off line, the largest fraction (grid
0.01) at which the limiting valve keeps ``BACKOFF_MARGIN`` and every controlled valve
``CONTROL_MARGIN`` at the steady state (mean of the last hour), and at which a run
toward that steady state itself (the grade's table) settles there again, the
limiting valve ``CUSHION`` further in; then that steady state as the grade's table
and the Downs & Vogel cost of it beside Ricker's optimum's (his state evaluated by
this model).

    PYTHONPATH=. python docs/te_modes.py          # about 1 wall minute

Prints the table rows for ``_STEADY`` and the measured table of the module's
docstring. The trial grades are put in place of ``grades.grade`` for the runs only.
"""

from __future__ import annotations

import contextlib
import math
import sys

import numpy as np

import controller.units.te.grades as G
from controller.units.te.control import run_te
from controller.units.te.max_production import BACKOFF_MARGIN, BACKOFFS, BackOff, interpolated
from plant_sim.tennessee_eastman import TESimulator

HOURS = 36.0
LAST = 100  # samples of the last hour
#: Room (% of range) the limiting valve keeps beyond BACKOFF_MARGIN in the table's own
#: run: at 36 h the cascade still drifts (up to 4 % over the last 10 h), and a table
#: right at the margin left mode 6's D feed 0.2 % past it in its own run.
CUSHION = 0.2


@contextlib.contextmanager
def trial_grade(name: str, xmeas, xmv):
    """``grades.grade(name)`` is the trial grade inside the block."""
    xmeas, xmv = np.array(xmeas), np.array(xmv)
    xmeas.setflags(write=False)
    xmv.setflags(write=False)
    trial = G.Grade(name, xmeas, xmv)
    real = G.grade

    def patched(value):
        return trial if G.parse_grade(value) == name else real(value)

    G.grade = patched
    try:
        yield trial
    finally:
        G.grade = real


def settle(b: BackOff, fraction: float, table=None) -> dict:
    """The cascade's steady state toward the back-off line at ``fraction``, or toward
    the grade ``table`` = (XMEAS, XMV) when given (the check of a stored table)."""
    bb = BackOff(b.grade, b.neighbour, b.limiting_valve, fraction)
    if table is None:
        xm, xv = interpolated(bb, G.ricker_optimum(bb.neighbour), G.ricker_optimum(bb.grade))
    else:
        xm, xv = table
    with trial_grade(b.grade, xm, xv):
        plan = G.TransitionPlan(b.neighbour, (G.Leg(1.0, b.grade),))
        run = run_te("ssmpc", plan, HOURS, noise=False)
    if run.shutdown is not None:
        return {"fraction": fraction, "trip": run.shutdown.reason, "ok": False}
    u = run.xmv[-LAST:].mean(axis=0)
    y = run.xmeas[-LAST:].mean(axis=0)
    lim = u[b.limiting_valve - 1]
    ok = BACKOFF_MARGIN <= lim <= 100 - BACKOFF_MARGIN and all(
        G.CONTROL_MARGIN <= u[v - 1] <= 100 - G.CONTROL_MARGIN for v in G.CONTROLLED_VALVES)
    if table is not None:  # the grade's own run: it settles where the table says
        ok = (ok and lim <= 100 - BACKOFF_MARGIN - CUSHION
              and abs(y[16] - xm[16]) <= 0.01 * xm[16] and abs(y[39] - xm[39]) <= 0.5
              and bool(np.all(np.abs(u[[0, 1, 3]] - xv[[0, 1, 3]]) <= 1.0)))
    return {"fraction": fraction, "trip": None, "ok": ok, "limiting": float(lim), "xmeas": y,
            "xmv": u, "cost": float(run.cost[-LAST:].mean()),
            "drift": float(np.max(np.abs(run.xmv[-1] - run.xmv[-10 * LAST])))}


def search(b: BackOff) -> dict:
    """Largest feasible fraction on the 0.01 grid: secant on the limiting valve, then
    down by 0.01 until feasible (and up while the next is feasible); then down by 0.01
    until the steady state's own table passes :func:`settle`'s check of a table."""
    best = _search_line(b)
    f = best["fraction"]
    while best["ok"] and f > -1.0:
        check = settle(b, f, (best["xmeas"], best["xmv"]))
        if check["ok"]:
            return best
        print(f"{b.grade}: {f:+.2f}: the table's own run settles with the limiting valve "
              f"at {check.get('limiting', float('nan')):.2f} %; one step back", flush=True)
        f = round(f - 0.01, 2)
        best = settle(b, f)
    return best


def _search_line(b: BackOff) -> dict:
    """:func:`search` on the back-off line alone."""
    a = settle(b, 0.0)
    c = settle(b, 0.5)
    slope = (c["limiting"] - a["limiting"]) / 0.5
    target = 100.0 - BACKOFF_MARGIN
    f = math.floor(100 * (target - a["limiting"]) / slope) / 100 if slope > 0 else 1.0
    f = min(max(f, -1.0), 1.0)
    best = settle(b, f)
    while not best["ok"] and f > -1.0:
        f = round(f - 0.01, 2)
        best = settle(b, f)
    while f < 1.0:
        nxt = settle(b, round(f + 0.01, 2))
        if not nxt["ok"]:
            break
        best, f = nxt, round(f + 0.01, 2)
    return best


def ricker_cost(name: str) -> tuple[float, float]:
    """Cost ($/h) and production (m3/h) of Ricker's optimum, evaluated by this model."""
    sim = TESimulator(mode=name[4:])
    return float(sim.cost()), float(sim.initial_xmeas[16])


def main() -> int:
    rows, table = [], []
    for name, b in BACKOFFS.items():
        res = search(b)
        if not res["ok"]:
            print(f"{name}: no feasible fraction ({res})", file=sys.stderr)
            return 1
        rc, rp = ricker_cost(name)
        r = G.ricker_optimum(name)
        rows.append(f"{name},xmeas," + ",".join(f"{v:.6g}" for v in res["xmeas"]))
        rows.append(f"{name},xmv," + ",".join(f"{v:.6g}" for v in res["xmv"]))
        table.append(f"{name[4:]}  XMV({b.limiting_valve})  {res['fraction']:+.2f}  "
                     f"{rp:.2f} -> {res['xmeas'][16]:.2f}  "
                     f"{r.xmv[b.limiting_valve - 1]:.1f} -> {res['limiting']:.2f}  "
                     f"{rc:.1f} -> {res['cost']:.1f}  (valve drift over the last 10 h "
                     f"{res['drift']:.2f} %)")
        print(table[-1], flush=True)
    print("\n".join(rows))
    print("\n".join(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
