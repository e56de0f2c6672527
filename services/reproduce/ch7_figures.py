"""Figures of seed chapter 7 (laid out like Figs. 7.3-7.16), from runs of
:mod:`services.reproduce.ch7`.

Plotting only: :func:`plot_case` takes finished runs (strategy -> TERun), writes three
PNGs atomically (controlled variables; valves; levels, cost, production and the
active model) and returns their paths. Every strategy of the runs is one line on every
panel (legend on the first panel of each figure), the case's main strategy (SSMPC, else
the fixed-model MPC) drawn thicker. The inner-loop set point panels (T_r*, P_r*) show
the cascade's strategies; the decentralized loops have no such set points.
"""

from __future__ import annotations

from pathlib import Path

from services.output import atomic_output
from services.reproduce.ch7_verdicts import LABEL

__all__ = ["plot_case"]

_MAIN_ORDER = ("ssmpc", "fixed")
_STYLE = {"ssmpc": {"color": "tab:blue"}, "fixed": {"color": "tab:orange"},
          "pi": {"color": "0.45"}, "plan": {"color": "tab:green", "ls": ":"},
          "decentralized": {"color": "tab:purple", "ls": "-."}}
#: Inner-loop set points of the cascade strategies (T_r*, three levels, P_r*).
_CASCADE_SETPOINTS = 5


def _figure(nrows: int, ncols: int, size):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False, sharex=True)
    return plt, fig, axes


def _save(plt, fig, path: Path) -> str:
    fig.tight_layout()
    with atomic_output(path, "wb", field="plot") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)
    return str(path)


def _style(key: str, main: str) -> dict:
    style = dict(_STYLE.get(key, {"color": "k"}))
    style["lw"] = 1.4 if key == main else 0.9
    return style


def _panel(ax, runs, main, col, label, ref=True, limit=None, source="xmeas"):
    for key, run in runs.items():
        data = getattr(run, source)
        if source == "setpoints" and data.shape[1] != _CASCADE_SETPOINTS:
            continue  # not a cascade strategy: it has no such set point
        ax.plot(run.t, data[:, col], label=LABEL.get(key, key), **_style(key, main))
    if ref and source == "xmeas":
        r = runs[main]
        ax.plot(r.t, r.ref[:, col], "k--", lw=0.8, label="reference")
    if limit is not None:
        ax.axhline(limit, color="r", lw=0.8, label="interlock")
    ax.set_ylabel(label, fontsize=8)


def _models_panel(ax, runs, main) -> None:
    """The active model of every strategy that has models, on one axis of model names."""
    names: list[str] = []
    for run in runs.values():
        names += [n for n in run.model_names if n not in names]
    for key, run in runs.items():
        if not run.model_names:
            continue
        pos = [names.index(n) + 1 for n in run.model_names]
        y = [pos[a] if a >= 0 else float("nan") for a in run.active]
        ax.step(run.t, y, where="post", label=LABEL.get(key, key), **_style(key, main))
    if names:
        ax.set_yticks(range(1, len(names) + 1), names)
        ax.legend(fontsize=7)
    ax.set_ylabel("active model", fontsize=8)


def plot_case(runs: dict, case, plot_dir: Path, name: str, title: str,
              main: str | None = None) -> list[str]:
    """Three figures for one case; ``runs`` maps strategy -> TERun, ``main`` is the
    strategy the seed's figures show (drawn thicker; its references dashed; default
    SSMPC, else the fixed-model MPC, else the first run)."""
    plot_dir = Path(plot_dir)
    if main is None or main not in runs:
        main = next((k for k in _MAIN_ORDER if k in runs), next(iter(runs)))
    out = []
    # 1. controlled variables (Figs. 7.3, 7.7, 7.9, 7.14)
    plt, fig, ax = _figure(3, 2, (11.0, 8.5))
    _panel(ax[0, 0], runs, main, 6, "reactor pressure [kPa]", limit=3000.0)
    _panel(ax[0, 1], runs, main, 10, "separator temperature [°C]")
    _panel(ax[1, 0], runs, main, 39, "G in product [mol %]")
    _panel(ax[1, 1], runs, main, 12, "separator pressure [kPa]")
    _panel(ax[2, 0], runs, main, 17, "stripper temperature [°C]")
    _panel(ax[2, 1], runs, main, 15, "stripper pressure [kPa]")
    ax[0, 0].legend(fontsize=7)
    for a in ax[-1]:
        a.set_xlabel("Time [h]")
    fig.suptitle(f"{title}: controlled variables")
    out.append(_save(plt, fig, plot_dir / f"{name}_cv.png"))
    # 2. valves (Figs. 7.4-7.5, 7.8, 7.10-7.11, 7.15)
    plt, fig, ax = _figure(4, 2, (11.0, 10.0))
    valves = ((0, "D feed XMV1 [%]"), (1, "E feed XMV2 [%]"), (2, "A feed XMV3 [%]"),
              (3, "A+C feed XMV4 [%]"), (5, "purge XMV6 [%]"), (10, "condenser CW XMV11 [%]"),
              (4, "recycle XMV5 [%]"), (8, "steam XMV9 [%]"))
    for a, (col, label) in zip(ax.ravel(), valves, strict=True):
        _panel(a, runs, main, col, label, ref=False, source="xmv")
        a.set_ylim(-5, 105)
    ax[0, 0].legend(fontsize=7)
    for a in ax[-1]:
        a.set_xlabel("Time [h]")
    fig.suptitle(f"{title}: valves")
    out.append(_save(plt, fig, plot_dir / f"{name}_valves.png"))
    # 3. loops, cost, production, model (Figs. 7.6, 7.11, 7.15-7.16)
    plt, fig, ax = _figure(3, 2, (11.0, 8.5))
    _panel(ax[0, 0], runs, main, 7, "reactor level [%]")
    _panel(ax[0, 1], runs, main, 0, "T_r* set point [°C]", ref=False, source="setpoints")
    _panel(ax[1, 0], runs, main, 16, "product flow XMEAS17 [m³/h]", ref=False)
    for key, run in runs.items():
        ax[1, 1].plot(run.t, run.cost, label=LABEL.get(key, key), **_style(key, main))
    ax[1, 1].set_ylabel("operating cost [$/h]", fontsize=8)
    ax[1, 1].legend(fontsize=7)
    _models_panel(ax[2, 0], runs, main)
    _panel(ax[2, 1], runs, main, 4, "P_r* set point [kPa]", ref=False, source="setpoints")
    for a in ax[-1]:
        a.set_xlabel("Time [h]")
    fig.suptitle(f"{title}: loops, cost, production, model")
    out.append(_save(plt, fig, plot_dir / f"{name}_loops.png"))
    return out
