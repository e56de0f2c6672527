"""Seed-result reproduction records for ``ssmpc reproduce ID``.

A study function takes a :class:`StudyContext` and returns a
:class:`ReproduceResult`; its JSON form (what scripts rely on) is
``{"id", "rows": [{"name", "unit", "seed", "ours"}], "verdict", "why", "figures"}``.

Verdicts (:data:`VERDICTS`) judge the seed's claim on what our run computed:

- ``reproduced``: our computation gives the printed number within the tolerance the
  ``why`` states.
- ``beaten``: ours is better than the printed number on the seed's own measure.
- ``differs``: outside the tolerance (the ``why`` says by how much and why).
- ``calibrated``: the match is the target of a fit (e.g. plant parameters
  reconstructed by fitting the printed models), so it proves the fit, not the
  method; the ``why`` says what was fitted to what. A fitted result that misses its
  own target is ``differs``.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Row", "ReproduceResult", "StudyContext", "discover_studies", "VERDICTS"]

VERDICTS = ("reproduced", "beaten", "differs", "calibrated")


@dataclass(frozen=True)
class Row:
    """One compared number. ``seed`` is exactly as printed in seed_results.md (or None)."""

    name: str
    unit: str
    seed: float | None
    ours: float

    def as_dict(self) -> dict:
        return {"name": self.name, "unit": self.unit, "seed": self.seed, "ours": float(self.ours)}


@dataclass
class ReproduceResult:
    id: str
    rows: list[Row]
    verdict: str
    why: str
    figures: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")
        if self.verdict in ("differs", "calibrated") and not self.why:
            raise ValueError(f"a {self.verdict!r} verdict needs a why")

    def as_dict(self) -> dict:
        return {
            "id": self.id,
            "rows": [r.as_dict() for r in self.rows],
            "verdict": self.verdict,
            "why": self.why,
            "figures": list(self.figures),
        }


@dataclass(frozen=True)
class StudyContext:
    """What a study may use: where to put figures (None = no figures), a seed, and how
    many processes may make its independent closed-loop runs (``workers``; the TE
    studies use them, the numbers do not depend on it)."""

    plot_dir: Path | None = None
    seed: int = 0
    quick: bool = False
    workers: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) \
                or self.workers < 1:
            raise ValueError(f"workers: expected an integer >= 1, got {self.workers!r}")


StudyFn = Callable[[StudyContext], ReproduceResult]


def discover_studies() -> dict[str, StudyFn]:
    """All ids registered by modules of :mod:`services.reproduce`."""
    import services.reproduce as pkg

    found: dict[str, StudyFn] = {}
    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"services.reproduce.{info.name}")
        for rid, fn in getattr(mod, "RESULTS", {}).items():
            if rid in found:
                raise RuntimeError(f"result id {rid} registered twice")
            found[rid] = fn
    return found
