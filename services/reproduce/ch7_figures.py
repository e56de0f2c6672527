"""Figures of seed chapter 7 (laid out like Figs. 7.3-7.16), from runs of
:mod:`services.reproduce.ch7`.

Plotting only: :func:`plot_case` takes finished runs (strategy -> TERun), writes three
PNGs atomically (controlled variables; valves; levels, cost, production and the
active model) and returns their paths. The PI baseline is drawn in grey on every
panel it shares with the MPC run.
"""

from __future__ import annotations

from pathlib import Path

from services.output import atomic_output

__all__ = ["plot_case"]

_MAIN_ORDER = ("ssmpc", "fixed")
_LABEL = {"ssmpc": "SSMPC", "fixed": "fixed-model MPC", "pi": "PI baseline"}


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


def _panel(ax, runs, main, col, label, ref=True, limit=None, source="xmeas"):
    for key, run in runs.items():
        data = getattr(run, source)[:, col]
        if key == main:
            ax.plot(run.t, data, "b", lw=1.1, label=_LABEL[key])
        elif key == "pi":
            ax.plot(run.t, data, color="0.55", lw=0.9, label=_LABEL[key])
    if ref and source == "xmeas":
        r = runs[main]
        ax.plot(r.t, r.ref[:, col], "k--", lw=0.8, label="reference")
    if limit is not None:
        ax.axhline(limit, color="r", lw=0.8, label="interlock")
    ax.set_ylabel(label, fontsize=8)


def plot_case(runs: dict, case, plot_dir: Path, name: str, title: str) -> list[str]:
    """Three figures for one case; ``runs`` maps strategy -> TERun."""
    plot_dir = Path(plot_dir)
    main = next(k for k in _MAIN_ORDER if k in runs) if any(
        k in runs for k in _MAIN_ORDER) else "pi"
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
        style = {"color": "b"} if key == main else {"color": "0.55"}
        if key in (main, "pi"):
            ax[1, 1].plot(run.t, run.cost, lw=1.0, label=_LABEL[key], **style)
    ax[1, 1].set_ylabel("operating cost [$/h]", fontsize=8)
    ax[1, 1].legend(fontsize=7)
    r = runs[main]
    if r.model_names:
        ax[2, 0].step(r.t, r.active + 1, where="post")
        ax[2, 0].set_yticks(range(1, len(r.model_names) + 1), list(r.model_names))
    ax[2, 0].set_ylabel("active model", fontsize=8)
    _panel(ax[2, 1], runs, main, 4, "P_r* set point [kPa]", ref=False, source="setpoints")
    for a in ax[-1]:
        a.set_xlabel("Time [h]")
    fig.suptitle(f"{title}: loops, cost, production, model")
    out.append(_save(plt, fig, plot_dir / f"{name}_loops.png"))
    return out
