"""Acceptance of a transition controller on a campaign: the product against every baseline.

A TE transition controller is accepted on the matrix of ``docs/campaigns/te_matrix.json``
by comparisons on the campaign's own metrics, the same seeds and cases for every
strategy (:mod:`services.campaign.metrics` computes them per run). This module
judges them from a campaign document; it runs nothing.

Transitions (cases with a leg), the product's median over seeds against each
baseline's:

- **faster**: the median ``time_to_grade_h`` at least :data:`FASTER_BY` (25 %)
  shorter than the best baseline's (a baseline with a trip or a seed that never
  reached the grade counts as never at grade);
- **cheaper**: the median ``transition_cost_usd`` lower than that of every baseline
  that reached the grade on all seeds;
- **peak**: the highest ``peak_pressure_kpa`` of any seed at most :data:`PEAK_LIMIT_KPA`
  (Downs & Vogel's normal high limit of the reactor pressure);
- **limits bind**, where *faster* fails: no baseline is faster than the product, and
  a plant limit binds through the transition (median ``limit_bound_share`` at least
  :data:`LIMITS_BIND_SHARE`). A baseline that is faster shows that the limits left room.

The transition is *met* when no seed tripped and the peak holds, the product is
cheaper, and it is faster or the limits bind.

Disturbances (cases without a leg), against ``decentralized``: mean
``mean_cost_usd_h`` and mean ``product_variability`` (G and production standard
deviations) over seeds no worse than the decentralized structure's, within
:data:`NO_WORSE_TOLERANCE`. A seed on which the baseline tripped counts for the
product if the product did not trip there (a trip is worse than any cost); the
case is *met* when the product never tripped and every measure holds.

Measured limits: bookkeeping only; the 1,110 rows of the acceptance matrix are judged
and written as Markdown in 4.6-6.6 ms (AMD EPYC, Python 3.11.7). The verdicts of that
matrix are in ``docs/te_matrix.md``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from statistics import median

__all__ = ["FASTER_BY", "LIMITS_BIND_SHARE", "NO_WORSE_TOLERANCE", "PEAK_LIMIT_KPA",
           "Acceptance", "DisturbanceVerdict", "TransitionVerdict", "judge", "to_markdown"]

#: Shortest relative gain in median time to grade over the best baseline.
FASTER_BY = 0.25
#: Highest reactor pressure allowed in a transition, kPa (Downs & Vogel's normal limit).
PEAK_LIMIT_KPA = 2895.0
#: Share of the transition window in which a plant limit must bind for the
#: "limits bind" evidence ("through the transition": at least three quarters).
LIMITS_BIND_SHARE = 0.75
#: Relative margin of "no worse" on the disturbance measures (noise between seeds).
NO_WORSE_TOLERANCE = 0.01


@dataclass(frozen=True)
class TransitionVerdict:
    """One transition case: the product's medians, the best baseline's, the verdict.

    Times in h, costs in $, pressures in kPa; ``None`` where no seed gives a value.
    """

    case: str
    seeds: int
    trips: int
    time_to_grade_h: float | None
    best_baseline: str | None
    best_baseline_time_h: float | None
    faster_by: float | None
    transition_cost_usd: float | None
    lowest_baseline_cost_usd: float | None
    peak_pressure_kpa: float | None
    limit_bound_share: float | None
    binding_limit: str | None
    faster: bool
    cheaper: bool
    peak_ok: bool
    limits_bind: bool
    met: bool
    baseline_times_h: dict = field(default_factory=dict)
    baseline_trips: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DisturbanceVerdict:
    """One disturbance case: the product against ``decentralized`` on the same seeds."""

    case: str
    seeds: int
    trips: int
    baseline_trips: int
    mean_cost_usd_h: float | None
    baseline_mean_cost_usd_h: float | None
    g_std_mol: float | None
    baseline_g_std_mol: float | None
    production_std_pct: float | None
    baseline_production_std_pct: float | None
    cost_ok: bool
    variability_ok: bool
    met: bool


@dataclass(frozen=True)
class Acceptance:
    """The verdicts of a campaign for ``product`` (empty lists where the doc has none)."""

    product: str
    baselines: tuple
    transitions: list
    disturbances: list
    trips: dict

    @property
    def met(self) -> bool:
        return (all(v.met for v in self.transitions)
                and all(v.met for v in self.disturbances) and not self.trips.get(self.product))

    def as_dict(self) -> dict:
        return {"product": self.product, "baselines": list(self.baselines), "met": self.met,
                "trips": dict(self.trips),
                "criteria": {"faster_by": FASTER_BY, "peak_limit_kpa": PEAK_LIMIT_KPA,
                             "limits_bind_share": LIMITS_BIND_SHARE,
                             "no_worse_tolerance": NO_WORSE_TOLERANCE},
                "transitions": [asdict(v) for v in self.transitions],
                "disturbances": [asdict(v) for v in self.disturbances]}


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(median(values)) if values else None


def _mean(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(sum(values) / len(values)) if values else None


def _tripped(row) -> bool:
    return bool(row.get("tripped"))


def _time(rows) -> float:
    """Median time to grade; never at grade (inf) when a seed tripped or did not reach it."""
    if any(_tripped(r) or r.get("time_to_grade_h") is None for r in rows):
        return math.inf
    return float(median(r["time_to_grade_h"] for r in rows))


def _finite(x: float) -> float | None:
    return None if x is None or math.isinf(x) else x


def _transition(case, product_rows, baseline_rows: dict) -> TransitionVerdict:
    t = _time(product_rows)
    times = {b: _time(rows) for b, rows in baseline_rows.items()}
    best = min(times, key=lambda b: times[b]) if times else None
    t_best = times[best] if best is not None else math.inf
    faster_by = None
    if not math.isinf(t) and not math.isinf(t_best) and t_best > 0:
        faster_by = 1.0 - t / t_best
    faster = (not math.isinf(t)) and (math.isinf(t_best) or (faster_by is not None
                                                             and faster_by >= FASTER_BY))
    cost = _median(r.get("transition_cost_usd") for r in product_rows)
    reached = [b for b in times if not math.isinf(times[b])]
    base_costs = [_median(r.get("transition_cost_usd") for r in baseline_rows[b])
                  for b in reached]
    base_costs = [c for c in base_costs if c is not None]
    lowest = min(base_costs) if base_costs else None
    cheaper = cost is not None and (lowest is None or cost < lowest)
    peaks = [r.get("peak_pressure_kpa") for r in product_rows
             if r.get("peak_pressure_kpa") is not None]
    peak = max(peaks) if peaks else None
    trips = sum(_tripped(r) for r in product_rows)
    peak_ok = peak is not None and peak <= PEAK_LIMIT_KPA
    share = _median(r.get("limit_bound_share") for r in product_rows)
    limits = [r.get("binding_limit") for r in product_rows if r.get("binding_limit")]
    # the most frequent; a tie goes to the first seed's (a set's order varies by process)
    binding = Counter(limits).most_common(1)[0][0] if limits else None
    limits_bind = (not faster and not math.isinf(t) and t <= t_best
                   and share is not None and share >= LIMITS_BIND_SHARE)
    met = trips == 0 and peak_ok and cheaper and (faster or limits_bind)
    return TransitionVerdict(
        case=case, seeds=len(product_rows), trips=trips, time_to_grade_h=_finite(t),
        best_baseline=best, best_baseline_time_h=_finite(t_best), faster_by=faster_by,
        transition_cost_usd=cost, lowest_baseline_cost_usd=lowest, peak_pressure_kpa=peak,
        limit_bound_share=share, binding_limit=binding, faster=faster, cheaper=cheaper,
        peak_ok=peak_ok, limits_bind=limits_bind, met=met,
        baseline_times_h={b: _finite(v) for b, v in times.items()},
        baseline_trips={b: sum(_tripped(r) for r in rows) for b, rows in baseline_rows.items()})


def _no_worse(mine, theirs) -> bool:
    return mine is not None and (theirs is None or mine <= theirs * (1.0 + NO_WORSE_TOLERANCE))


def _disturbance(case, product_rows, baseline_rows) -> DisturbanceVerdict:
    by_seed = {r["seed"]: r for r in baseline_rows}
    cost_ok = variability_ok = True
    both = []
    for r in product_rows:
        b = by_seed.get(r["seed"])
        if _tripped(r):
            cost_ok = variability_ok = False
        elif b is not None and not _tripped(b):
            both.append((r, b))

    def var(row, key):
        return (row.get("product_variability") or {}).get(key)

    mine = [_mean(r.get("mean_cost_usd_h") for r, _ in both),
            _mean(var(r, "g_std_mol") for r, _ in both),
            _mean(var(r, "production_std_pct") for r, _ in both)]
    theirs = [_mean(b.get("mean_cost_usd_h") for _, b in both),
              _mean(var(b, "g_std_mol") for _, b in both),
              _mean(var(b, "production_std_pct") for _, b in both)]
    if both:
        cost_ok = cost_ok and _no_worse(mine[0], theirs[0])
        variability_ok = (variability_ok and _no_worse(mine[1], theirs[1])
                          and _no_worse(mine[2], theirs[2]))
    trips = sum(_tripped(r) for r in product_rows)
    return DisturbanceVerdict(
        case=case, seeds=len(product_rows), trips=trips,
        baseline_trips=sum(_tripped(b) for b in baseline_rows),
        mean_cost_usd_h=mine[0], baseline_mean_cost_usd_h=theirs[0],
        g_std_mol=mine[1], baseline_g_std_mol=theirs[1],
        production_std_pct=mine[2], baseline_production_std_pct=theirs[2],
        cost_ok=cost_ok, variability_ok=variability_ok,
        met=trips == 0 and cost_ok and variability_ok)


def judge(doc: dict, product: str = "ssmpc",
          disturbance_baseline: str = "decentralized") -> Acceptance:
    """Judge the campaign document ``doc`` (``results.json``) for ``product``.

    Rows that failed (``error``) are left out. The baselines are every other strategy
    of the document. Cases where the product has no row are left out.
    """
    from services.campaign.figures import group_runs

    cases, strategies, groups = group_runs(r for r in doc.get("runs", []) if not r.get("error"))
    legs = dict.fromkeys(cases, 0)
    trips = dict.fromkeys(strategies, 0)
    for (case, strategy), rows in groups.items():
        legs[case] = max(legs[case], *(int(r.get("legs") or 0) for r in rows))
        trips[strategy] += sum(_tripped(r) for r in rows)
    baselines = tuple(s for s in strategies if s != product)
    transitions, disturbances = [], []
    for case in cases:
        mine = groups.get((case, product))
        if not mine:
            continue
        if legs[case]:
            transitions.append(_transition(
                case, mine, {b: groups[(case, b)] for b in baselines if (case, b) in groups}))
        elif (case, disturbance_baseline) in groups:
            disturbances.append(_disturbance(case, mine, groups[(case, disturbance_baseline)]))
    return Acceptance(product, baselines, transitions, disturbances, trips)


def _f(x, fmt="{:.1f}") -> str:
    return "-" if x is None else fmt.format(x)


def _yes(ok: bool) -> str:
    return "yes" if ok else "no"


def _baseline_cell(v: TransitionVerdict, b: str) -> str:
    if v.baseline_trips.get(b):
        return f"trip {v.baseline_trips[b]}/{v.seeds}"
    t = v.baseline_times_h.get(b)
    return "never" if t is None and b in v.baseline_times_h else _f(t)


def to_markdown(acc: Acceptance) -> str:
    """The verdicts as Markdown tables (transitions, disturbances, trips)."""
    out = []
    if acc.transitions:
        names = list(acc.baselines)
        out.append(f"| case | {acc.product} h | " + " | ".join(f"{b} h" for b in names)
                   + " | faster by | $ | lowest baseline $ | peak kPa | limit bound | "
                   "faster | cheaper | peak | limits bind | met |")
        out.append("|---" * (len(names) + 12) + "|")
        for v in acc.transitions:
            mine = (f"trip {v.trips}/{v.seeds}" if v.trips
                    else ("never" if v.time_to_grade_h is None else _f(v.time_to_grade_h)))
            share = ("-" if v.limit_bound_share is None
                     else f"{v.limit_bound_share:.2f} {v.binding_limit or ''}".strip())
            out.append(f"| {v.case} | {mine} | " + " | ".join(_baseline_cell(v, b) for b in names)
                       + f" | {_f(v.faster_by, '{:+.0%}')} | {_f(v.transition_cost_usd, '{:.0f}')}"
                       f" | {_f(v.lowest_baseline_cost_usd, '{:.0f}')}"
                       f" | {_f(v.peak_pressure_kpa, '{:.0f}')} | {share} | {_yes(v.faster)}"
                       f" | {_yes(v.cheaper)} | {_yes(v.peak_ok)} | {_yes(v.limits_bind)}"
                       f" | {_yes(v.met)} |")
        out.append("")
    if acc.disturbances:
        out.append(f"| case | {acc.product} trips | baseline trips | $/h | baseline $/h | "
                   "G std mol % | baseline | production std % | baseline | cost | "
                   "variability | met |")
        out.append("|---" * 12 + "|")
        for v in acc.disturbances:
            out.append(
                f"| {v.case} | {v.trips}/{v.seeds} | {v.baseline_trips}/{v.seeds}"
                f" | {_f(v.mean_cost_usd_h, '{:.2f}')} | {_f(v.baseline_mean_cost_usd_h, '{:.2f}')}"
                f" | {_f(v.g_std_mol, '{:.3f}')} | {_f(v.baseline_g_std_mol, '{:.3f}')}"
                f" | {_f(v.production_std_pct, '{:.2f}')}"
                f" | {_f(v.baseline_production_std_pct, '{:.2f}')}"
                f" | {_yes(v.cost_ok)} | {_yes(v.variability_ok)} | {_yes(v.met)} |")
        out.append("")
    met_t = sum(v.met for v in acc.transitions)
    met_d = sum(v.met for v in acc.disturbances)
    trips = ", ".join(f"{s} {n}" for s, n in acc.trips.items())
    out.append(f"Transitions met: {met_t} of {len(acc.transitions)}; disturbance cases met: "
               f"{met_d} of {len(acc.disturbances)}; runs tripped: {trips}.")
    return "\n".join(out) + "\n"
