"""Figures of seed chapter 6 (Figs. 6.1–6.5), drawn from runs of :mod:`services.reproduce.ch6`.

Plotting only: every function takes finished runs and a path, writes one PNG atomically
and returns the list of written paths.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.output import atomic_output

__all__ = ["plot_reactor", "plot_calcium"]


def _figure(nrows: int, ncols: int, size=(10.0, 7.0)):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False)
    return plt, fig, axes


def _save(plt, fig, path: Path) -> list[str]:
    fig.tight_layout()
    with atomic_output(path, "wb", field="plot") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return [str(path)]


def plot_reactor(run, path: Path, title: str, p_limit: float) -> list[str]:
    """Figs. 6.1–6.3: F4, P, yA3 with set point and reference; valves; active model."""
    plt, fig, ax = _figure(2, 3, (13.0, 7.0))
    t = run.t
    panels = ((ax[0, 0], 2, "F4 production rate [kmol/h]"),
              (ax[0, 1], 0, "P reactor pressure [kPa]"),
              (ax[1, 0], 1, "yA3, A in the purge [mol %]"))
    for a, i, label in panels:
        if not np.allclose(run.y_meas[:, i], run.y_true[:, i]):
            a.plot(t, run.y_meas[:, i], color="0.75", lw=0.6, label="measured / inferred")
        a.plot(t, run.y_true[:, i], "b", lw=1.2, label="plant")
        a.plot(t, run.setpoint[:, i], "k--", lw=1.0, label="set point")
        a.plot(t, run.reference[:, i], "k:", lw=1.0, label="reference")
        a.set_xlabel("Time [h]")
        a.set_ylabel(label)
    ax[0, 1].axhline(p_limit, color="r", lw=0.8, label="limit")
    ax[0, 0].legend(fontsize=7)
    ax[0, 1].legend(fontsize=7)
    for j, name in enumerate(("x1 feed 1", "x2 feed 2", "x3 purge")):
        ax[1, 1].plot(t, run.u[:, j], label=name)
    ax[1, 1].set_xlabel("Time [h]")
    ax[1, 1].set_ylabel("valve position [%]")
    ax[1, 1].legend(fontsize=7)
    ax[1, 2].step(t, run.active + 1, where="post")
    ax[1, 2].set_yticks(range(1, len(run.model_names) + 1), list(run.model_names))
    ax[1, 2].set_xlabel("Time [h]")
    ax[1, 2].set_ylabel("active model")
    ax[0, 2].plot(t, run.solve_ms, ".", ms=2)
    ax[0, 2].set_xlabel("Time [h]")
    ax[0, 2].set_ylabel("MPC solve time [ms]")
    fig.suptitle(title)
    return _save(plt, fig, path)


def plot_calcium(runs: dict, path: Path) -> list[str]:
    """Figs. 6.4–6.5: xp5, xp6 with set point and reference; J and q1; weights 50/1
    vs 1/1 for OPI → OPII."""
    plt, fig, ax = _figure(4, 2, (11.0, 11.0))
    for col, key in enumerate(("OPII->OPI", "OPI->OPII")):
        run = runs[key]
        for row, (i, name) in enumerate(((0, "xp5 cytosol Ca [µM]"), (1, "xp6 SR Ca [µM]"))):
            a = ax[row, col]
            a.plot(run.t, run.y[:, i], "b", label="output, weights 50/1")
            a.plot(run.t, run.reference[:, i], "k:", label="reference")
            a.axhline(run.setpoint[i], color="k", ls="--", lw=0.8, label="set point")
            if key == "OPI->OPII" and i == 0 and "OPI->OPII 1/1" in runs:
                w1 = runs["OPI->OPII 1/1"]
                a.plot(w1.t, w1.y[:, 0], "g-.", label="weights 1/1")
            a.set_ylabel(name)
            a.set_title(key.replace("->", " → "), fontsize=9)
            a.legend(fontsize=7)
        a = ax[2, col]
        a.plot(run.t, run.u[:, 0], label="J (>= 0) [µM/s]")
        a.plot(run.t, run.u[:, 1] - run.u[0, 1], label="q1 change [µM/s]")
        a.set_ylabel("inputs")
        a.legend(fontsize=7)
        a = ax[3, col]
        a.step(run.t, run.active + 1, where="post")
        a.set_yticks(range(1, len(run.model_names) + 1), list(run.model_names))
        a.set_xlabel("Time [s]")
        a.set_ylabel("active model")
    fig.suptitle("Calcium MPC (P = 10, M = 4, weights 50/1), reconstructed plant")
    return _save(plt, fig, path)
