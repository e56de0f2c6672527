"""The campaign's matrix figure: cases × strategies, colour = time to grade or trip.

Plotting only, from the rows of a campaign document (:func:`cell_summaries` does
the counting, :func:`plot_matrix` the drawing). A cell holds every seed of one
(case, strategy):

- some seed tripped: red, ``trip k/n`` and the earliest trip time;
- every seed reached the grade: the median ``time_to_grade_h`` on a colour scale
  shared by the whole figure (viridis, short = dark);
- a case with legs whose grade was not reached by some seed: grey, ``not reached``;
- a case without legs (a disturbance held): light green, ``held`` and the
  highest reactor pressure;
- a run that failed: black, ``error``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from services.output import atomic_output

__all__ = ["cell_summaries", "group_runs", "plot_matrix"]


def group_runs(rows) -> tuple[list[str], list[str], dict[tuple[str, str], list[dict]]]:
    """Cases, strategies (in the rows' order) and the rows of each (case, strategy)."""
    cases: list[str] = []
    strategies: list[str] = []
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        if row["case"] not in cases:
            cases.append(row["case"])
        if row["strategy"] not in strategies:
            strategies.append(row["strategy"])
        groups.setdefault((row["case"], row["strategy"]), []).append(row)
    return cases, strategies, groups


def cell_summaries(doc: dict) -> tuple[list[str], list[str], dict]:
    """Cases, strategies (in document order) and per (case, strategy) a summary dict."""
    cases, strategies, groups = group_runs(doc["runs"])
    cells = {}
    for key, rows in groups.items():
        n = len(rows)
        errors = sum(bool(r.get("error")) for r in rows)
        trips = [r["trip"]["at_h"] for r in rows if r.get("tripped") and r.get("trip")]
        ttg = [r["time_to_grade_h"] for r in rows if r.get("time_to_grade_h") is not None]
        peaks = [r["peak_pressure_kpa"] for r in rows if r.get("peak_pressure_kpa") is not None]
        has_legs = any(r.get("legs") for r in rows)
        if errors:
            kind = "error"
        elif trips:
            kind = "trip"
        elif len(ttg) == n:
            kind = "grade"
        elif has_legs:
            kind = "not reached"
        else:
            kind = "held"
        cells[key] = {"kind": kind, "n": n, "errors": errors, "trips": len(trips),
                      "first_trip_h": min(trips) if trips else None,
                      "time_to_grade_h": float(np.median(ttg)) if len(ttg) == n else None,
                      "peak_pressure_kpa": max(peaks) if peaks else None}
    return cases, strategies, cells


def plot_matrix(doc: dict, path: str | Path, title: str | None = None) -> str:
    """Draw the matrix figure of a campaign document into ``path`` (PNG, atomic)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    cases, strategies, cells = cell_summaries(doc)
    grades = [c["time_to_grade_h"] for c in cells.values() if c["kind"] == "grade"]
    norm = Normalize(0.0, max(grades) if grades else 1.0)
    cmap = plt.get_cmap("viridis")
    fixed = {"trip": "#d62728", "not reached": "#9e9e9e", "held": "#c7e9c0",
             "error": "#000000"}
    width = 1.6 + 1.7 * len(strategies)
    height = 1.3 + 0.55 * len(cases)
    fig, ax = plt.subplots(figsize=(width, height))
    for i, case in enumerate(cases):
        for j, strat in enumerate(strategies):
            c = cells.get((case, strat))
            if c is None:
                continue
            if c["kind"] == "grade":
                color = cmap(norm(c["time_to_grade_h"]))
                text = f"{c['time_to_grade_h']:.1f} h"
                dark = norm(c["time_to_grade_h"]) < 0.6
            else:
                color = fixed[c["kind"]]
                dark = c["kind"] in ("trip", "error")
                if c["kind"] == "trip":
                    text = f"trip {c['trips']}/{c['n']}\n@ {c['first_trip_h']:.1f} h"
                elif c["kind"] == "held":
                    peak = c["peak_pressure_kpa"]
                    text = "held" + ("" if peak is None else f"\n{peak:.0f} kPa")
                else:
                    text = c["kind"]
            ax.add_patch(plt.Rectangle((j, i), 1, 1, facecolor=color, edgecolor="white",
                                       linewidth=2))
            ax.text(j + 0.5, i + 0.5, text, ha="center", va="center", fontsize=8,
                    color="white" if dark else "black")
    ax.set_xlim(0, len(strategies))
    ax.set_ylim(len(cases), 0)
    ax.set_xticks(np.arange(len(strategies)) + 0.5, strategies)
    ax.set_yticks(np.arange(len(cases)) + 0.5, cases)
    ax.tick_params(length=0)
    for side in ax.spines.values():
        side.set_visible(False)
    ax.set_xlabel("strategy")
    ax.set_ylabel("case")
    runs = len(doc["runs"])
    ax.set_title(title or f"campaign {doc['campaign']} ({doc.get('unit', '')}, {runs} runs): "
                 "time to grade", fontsize=9)
    if grades:
        sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=ax, label="time to grade, h (median over seeds)", shrink=0.8)
    fig.tight_layout()
    with atomic_output(Path(path), "wb", field="out") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)
    return str(path)
