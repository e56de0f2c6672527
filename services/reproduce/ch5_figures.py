"""Figures of seed chapter 5 (Figs. 5.3-5.22): response with reference, control action
and the active model over time; parameter trajectories. Plotting only; the runs come
from :mod:`services.reproduce.ch5`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from services.output import atomic_output

__all__ = ["plot_transition", "plot_comparison", "plot_parameters"]


def _save(fig, path: Path) -> str:
    with atomic_output(path, "wb", field="plot") as fh:
        fig.savefig(fh, format="png", dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return str(path)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_transition(path: Path, res, title: str, y_label: str, u_label: str,
                    time_label: str, reference=None) -> str:
    """Seed layout: top response + reference, bottom left control, bottom right model."""
    plt = _pyplot()
    fig = plt.figure(figsize=(9, 7))
    ax = fig.add_subplot(2, 1, 1)
    ref = res.r[:, 0] if reference is None else reference
    ax.plot(res.t, res.y[:, 0], "--", label="response")
    ax.plot(res.t, ref, "-", label="reference")
    ax.set_ylabel(y_label)
    ax.set_title(title)
    ax.legend()
    ax2 = fig.add_subplot(2, 2, 3)
    ax2.plot(res.t, res.u[:, 0])
    ax2.set_xlabel(time_label)
    ax2.set_ylabel(u_label)
    ax3 = fig.add_subplot(2, 2, 4)
    ax3.step(res.t, res.active + 1, where="post")
    ax3.set_yticks(range(1, len(res.model_names) + 1))
    ax3.set_yticklabels([f"{i + 1}: {n}" for i, n in enumerate(res.model_names)])
    ax3.set_xlabel(time_label)
    ax3.set_ylabel("model")
    fig.tight_layout()
    return _save(fig, path)


def plot_comparison(path: Path, runs: Mapping[str, object], title: str, y_label: str,
                    time_label: str) -> str:
    """Several runs' responses against the common reference (Figs. 5.21, 5.22)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    first = next(iter(runs.values()))
    ax.plot(first.t, first.r[:, 0], "-", color="k", label="reference")
    for style, (label, res) in zip(("--", ":", "-."), runs.items()):
        ax.plot(res.t, res.y[:, 0], style, label=label)
    ax.set_xlabel(time_label)
    ax.set_ylabel(y_label)
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    return _save(fig, path)


def plot_parameters(path: Path, t: np.ndarray, params: np.ndarray, names: Sequence[str],
                    title: str, time_label: str) -> str:
    """Adaptive parameters over time (Figs. 5.4, 5.14), one panel each."""
    plt = _pyplot()
    n = params.shape[1]
    fig, axes = plt.subplots(2, (n + 1) // 2, figsize=(9, 6), squeeze=False)
    for i in range(n):
        ax = axes.flat[i]
        ax.plot(t, params[:, i])
        ax.set_ylabel(names[i])
        ax.set_xlabel(time_label)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)
