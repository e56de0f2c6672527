"""Figures of seed chapter 3 (Figs. 3.4-3.19): responses of the nonlinear plant,
the full-order and reduced linear models and the state-shared model to random
input perturbations. Plotting only; the numbers come from :mod:`services.reproduce.ch3`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from services.output import atomic_output

__all__ = ["plot_responses"]

# seed line styles: nonlinear solid + o, full-order solid/dotted + triangle, reduced dashed + square
STYLES = {
    "NL": {"ls": "-", "marker": "o", "color": "k"},
    "FL": {"ls": ":", "marker": "^", "color": "tab:blue"},
    "RE": {"ls": "--", "marker": "s", "color": "tab:red"},
    "SS": {"ls": "--", "marker": "s", "color": "tab:green"},
    "4L": {"ls": ":", "marker": "^", "color": "tab:blue"},
}
LABELS = {
    "NL": "nonlinear system",
    "FL": "full-order linear model",
    "4L": "minimal (4th-order) linear model",
    "RE": "reduced-order linear model",
    "SS": "state-shared model",
}


def plot_responses(path: Path, t: np.ndarray, series: Mapping[str, np.ndarray],
                   output_names: Sequence[str], output_units: Sequence[str], title: str,
                   time_unit: str = "h") -> str:
    """One panel per output with the given responses overlaid; returns the file path.

    ``series`` maps a key of :data:`LABELS` to an array of shape (len(t), n_outputs).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(output_names)
    fig, axes = plt.subplots(n, 1, figsize=(7.0, 2.3 * n), sharex=True, squeeze=False)
    every = max(1, len(t) // 40)
    for i, ax in enumerate(axes[:, 0]):
        for key, y in series.items():
            st = STYLES.get(key, {"ls": "-", "marker": None, "color": None})
            ax.plot(t, y[:, i], ls=st["ls"], color=st["color"], lw=1.0, marker=st["marker"],
                    markevery=every, ms=4, mfc="none", label=LABELS.get(key, key))
        ax.set_ylabel(f"{output_names[i]} [{output_units[i]}]")
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_title(title, fontsize=10)
    axes[0, 0].legend(fontsize=8, loc="best")
    axes[-1, 0].set_xlabel(f"Time [{time_unit}]")
    fig.tight_layout()
    with atomic_output(path, "wb", field="plot") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return str(path)
