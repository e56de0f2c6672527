"""Key performance indicators of an advanced controller, as an APC engineer reads them.

What commercial APC packages report per controller (DMC3, Profit Controller):

- **service factor**: the share of time the controller is ON and in control, i.e.
  not in fallback (a held move, a missed deadline, a failed step). The time of the
  window counts OFF, WARM and the time no controller ran at all (``down``: a gap in
  the samples longer than :attr:`KPISettings.gap_samples` periods, e.g. a controller
  restart) against it;
- **constraint activity** per variable: the share of the samples ON at which the
  variable sat at its low or its high limit (the at-limit flags of the status,
  :func:`controller.units.variables.at_limit_flags`);
- **operating cost against the base case**: the time-mean cost, $/h, beside the
  unit's documented base-case cost and their difference (negative: cheaper than the
  base case, the "benefit");
- **prediction error per model**: the mean of each model's RMS prediction error
  (:meth:`controller.switching.PerformanceIndex.rms_error`, units of the CVs' scales).

:class:`KPIAccumulator` is fed once per sample and keeps sums, never the samples: since
the start, and over trailing windows of process time (1 h and 24 h by default), each
a ring of :attr:`KPISettings.buckets` fixed buckets. A window reports its last
``buckets`` buckets, the current one included, so it covers between
``(1 - 1/buckets)`` and all of its length (the report gives the hours it covers). An
update costs O(number of variables + models) and at most ``buckets`` bucket clears
per window (after a gap), whatever the time run. Its sums go into the controller's
checkpoint (:meth:`KPIAccumulator.checkpoint`), so a restart goes on counting.

Time: a sample accounts for the process time since the sample before it (one
sample period for the first one, and when the process time goes back: a restarted
plant). A gap beyond ``gap_samples`` periods counts one period in the sample's mode
and the rest as ``down``; shorter gaps (measurements dropped under load) count
wholly in the sample's mode.

Measured cost of an update (this 2-core machine, TE's 41 CVs + 12 MVs and 8 models,
two windows): see ``docs/kpis.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.operator_modes import CONTROLLER_MODES
from controller.packing import pack_array, unpack_array

__all__ = ["KPISettings", "KPIAccumulator", "TIME_STATES"]

#: How the time of a window is split: ON in control, ON in fallback, WARM, OFF, and no
#: controller running.
TIME_STATES = ("on", "fallback", "warm", "off", "down")
_T = {s: i for i, s in enumerate(TIME_STATES)}
_N_ON = 5      # samples ON with at-limit flags (the activity's denominator)
_COST_T = 6    # process seconds with a cost
_COST_INT = 7  # cost integral, $/h * s
_HEAD = 8


@dataclass(frozen=True)
class KPISettings:
    """How the KPIs are counted.

    Attributes
    ----------
    sample_period_s : float
        The unit's sample period, process s (> 0).
    windows_h : tuple of float
        Trailing windows, process hours, increasing (default 1 h and 24 h).
    buckets : int
        Buckets per window (2..1000): the window's resolution is ``window / buckets``.
    gap_samples : float
        A gap between samples longer than this many periods is ``down`` time (>= 1).
    base_cost_usd_h : float or None
        The unit's base-case operating cost, $/h (None: the unit has none).
    base_cost_origin : str
        Where the base-case cost comes from.
    """

    sample_period_s: float
    windows_h: tuple[float, ...] = (1.0, 24.0)
    buckets: int = 24
    gap_samples: float = 5.0
    base_cost_usd_h: float | None = None
    base_cost_origin: str = ""

    def __post_init__(self) -> None:
        if not (isinstance(self.sample_period_s, int | float)
                and math.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise ValueError(f"sample_period_s: expected a finite number > 0, got "
                             f"{self.sample_period_s!r}")
        w = tuple(float(x) for x in self.windows_h)
        if any(not (math.isfinite(x) and x > 0) for x in w) or list(w) != sorted(set(w)):
            raise ValueError(f"windows_h: expected increasing finite hours > 0, got "
                             f"{self.windows_h!r}")
        object.__setattr__(self, "windows_h", w)
        if isinstance(self.buckets, bool) or not isinstance(self.buckets, int) \
                or not 2 <= self.buckets <= 1000:
            raise ValueError(f"buckets: expected an integer in 2..1000, got {self.buckets!r}")
        if not (math.isfinite(self.gap_samples) and self.gap_samples >= 1):
            raise ValueError(f"gap_samples: expected a number >= 1, got {self.gap_samples!r}")
        if self.base_cost_usd_h is not None and not math.isfinite(self.base_cost_usd_h):
            raise ValueError("base_cost_usd_h: expected a finite number or None")


class _Ring:
    """Sums over the buckets of one trailing window (bucket ``b`` covers the clock's
    ``[b w, (b + 1) w)``; the current one is ``index``)."""

    def __init__(self, width_s: float, n: int, fields: int) -> None:
        self.width_s = width_s
        self.sums = np.zeros((n, fields))
        self.index = 0

    def advance_to(self, bucket: int) -> None:
        """Make ``bucket`` the current one, clearing those it passes over."""
        n = len(self.sums)
        if bucket <= self.index:
            return
        if bucket - self.index >= n:
            self.sums[:] = 0.0
        else:
            for b in range(self.index + 1, bucket + 1):
                self.sums[b % n] = 0.0
        self.index = bucket

    def add(self, clock_s: float, x: np.ndarray) -> None:
        self.advance_to(int(clock_s // self.width_s))
        self.sums[self.index % len(self.sums)] += x

    def add_down(self, c0: float, c1: float) -> None:
        """``down`` time over the clock's ``[c0, c1)``, spread over its buckets."""
        w, n = self.width_s, len(self.sums)
        c0 = max(c0, c1 - n * w)  # older than the window: gone anyway
        while c0 < c1:
            b = int(c0 // w)
            end = min(c1, (b + 1) * w)
            self.advance_to(b)
            self.sums[b % n, _T["down"]] += end - c0
            c0 = end

    def total(self) -> np.ndarray:
        return self.sums.sum(axis=0)


class KPIAccumulator:
    """Counts the KPIs of one controller (module docstring).

    Parameters
    ----------
    settings : KPISettings
    variables : sequence of (name, kind)
        The variables whose constraint activity is counted, in the order of the
        at-limit flags given to :meth:`update` (kind ``"cv"`` or ``"mv"``).
    models : sequence of str, optional
        Model names, in the order of the prediction errors; when empty they are taken
        from the first :meth:`update` that gives them.
    """

    def __init__(self, settings: KPISettings, variables, models=()) -> None:
        self.settings = settings
        self.variables = tuple((str(n), str(k)) for n, k in variables)
        self.models: tuple[str, ...] = ()
        self._nv = len(self.variables)
        self._fields = _HEAD + 2 * self._nv
        self.totals = np.zeros(self._fields)
        self.rings = [_Ring(h * 3600.0 / settings.buckets, settings.buckets, self._fields)
                      for h in settings.windows_h]
        self.clock_s = 0.0
        self.last_t_s: float | None = None
        self.last_cost_usd_h: float | None = None
        self.last_rms: np.ndarray | None = None
        self.samples = 0
        if models:
            self._adopt_models(tuple(models))

    # -- feeding ---------------------------------------------------------------------
    def _adopt_models(self, models: tuple[str, ...]) -> None:
        self.models = tuple(str(m) for m in models)
        extra = np.zeros(2 * len(self.models))
        self.totals = np.concatenate((self.totals, extra))
        for r in self.rings:
            r.sums = np.hstack((r.sums, np.zeros((len(r.sums), len(extra)))))
        self._fields = len(self.totals)

    def update(self, t_s: float, mode: str, fallback: bool, at_lo=None, at_hi=None,
               cost_usd_h: float | None = None, prediction_rms=None, models=None) -> None:
        """Account for one sample.

        Parameters
        ----------
        t_s : float
            Process time of the sample, s.
        mode : str
            Controller mode at the sample (``off``, ``warm``, ``on``).
        fallback : bool
            The move written was not the controller's own (held, previous plan).
        at_lo, at_hi : array_like of bool, shape (n_variables,), optional
            Which variables sit at their low / high limit; None: not known this sample
            (not counted in the activity).
        cost_usd_h : float, optional
            Operating cost now, $/h (None or NaN: none).
        prediction_rms : array_like, shape (n_models,), optional
            Each model's RMS prediction error now (NaN entries are skipped).
        models : sequence of str, optional
            Names of ``prediction_rms``' models; errors of other names than the ones
            held are not counted.
        """
        if mode not in CONTROLLER_MODES:
            raise ValueError(f"mode: expected one of {', '.join(CONTROLLER_MODES)}, "
                             f"got {mode!r}")
        if not math.isfinite(t_s):
            raise ValueError("t_s: must be finite")
        ts = self.settings.sample_period_s
        gap = 0.0
        if self.last_t_s is None or t_s <= self.last_t_s:
            dt = ts
        else:
            dt = t_s - self.last_t_s
            if dt > self.settings.gap_samples * ts:
                gap, dt = dt - ts, ts
        self.last_t_s = float(t_s)
        x = np.zeros(self._fields)
        state = "fallback" if (mode == "on" and fallback) else mode
        x[_T[state]] = dt
        nv = self._nv
        if mode == "on" and at_lo is not None and at_hi is not None:
            x[_N_ON] = 1.0
            x[_HEAD:_HEAD + nv] = np.asarray(at_lo, dtype=bool)
            x[_HEAD + nv:_HEAD + 2 * nv] = np.asarray(at_hi, dtype=bool)
        if cost_usd_h is not None and math.isfinite(cost_usd_h):
            x[_COST_T] = dt
            x[_COST_INT] = cost_usd_h * dt
            self.last_cost_usd_h = float(cost_usd_h)
        if prediction_rms is not None:
            names = tuple(models) if models is not None else self.models
            if not self.models and names:
                self._adopt_models(names)
                x = np.concatenate((x, np.zeros(2 * len(names))))
            rms = np.asarray(prediction_rms, dtype=float)
            if names == self.models and rms.shape == (len(self.models),):
                ok = np.isfinite(rms)
                base = _HEAD + 2 * nv
                m = len(self.models)
                x[base:base + m] = np.where(ok, rms, 0.0)
                x[base + m:base + 2 * m] = ok
                self.last_rms = rms.copy()
        if gap > 0.0:
            self.totals[_T["down"]] += gap
            for r in self.rings:
                r.add_down(self.clock_s, self.clock_s + gap)
            self.clock_s += gap
        self.clock_s += dt
        self.totals += x
        for r in self.rings:
            # the sample's interval ends at the clock: it belongs to the bucket it ends in
            r.add(math.nextafter(self.clock_s, -math.inf), x)
        self.samples += 1

    # -- reading ---------------------------------------------------------------------
    def _window(self, name: str, length_h: float | None, s: np.ndarray) -> dict:
        total = float(s[:5].sum())
        share = {k: (float(s[i]) / total if total > 0 else None)
                 for k, i in _T.items()}
        n_on = float(s[_N_ON])
        nv = self._nv
        activity = []
        for j, (name_j, kind) in enumerate(self.variables):
            lo, hi = s[_HEAD + j], s[_HEAD + nv + j]
            activity.append({"name": name_j, "kind": kind,
                             "at_lo": float(lo / n_on) if n_on else None,
                             "at_hi": float(hi / n_on) if n_on else None,
                             "active": float((lo + hi) / n_on) if n_on else None})
        base = self.settings.base_cost_usd_h
        mean_cost = float(s[_COST_INT] / s[_COST_T]) if s[_COST_T] > 0 else None
        m = len(self.models)
        b = _HEAD + 2 * nv
        rms = {name_m: (float(s[b + i] / s[b + m + i]) if s[b + m + i] > 0 else None)
               for i, name_m in enumerate(self.models)}
        return {"window": name, "length_h": length_h, "hours": total / 3600.0,
                "service_factor": share["on"], "time_share": share,
                "samples_on": int(round(n_on)),
                "cost": {"mean_usd_h": mean_cost, "base_usd_h": base,
                         "vs_base_usd_h": (None if mean_cost is None or base is None
                                           else mean_cost - base),
                         "hours": float(s[_COST_T]) / 3600.0},
                "constraint_activity": activity, "prediction_rms": rms}

    def report(self) -> dict:
        """The KPIs since the start and over each trailing window.

        Returns
        -------
        dict
            ``{"samples", "process_time_s", "base_cost_usd_h", "base_cost_origin",
            "cost_now_usd_h", "prediction_rms_now", "windows": [...]}``; each window
            ``{"window", "length_h", "hours", "service_factor", "time_share",
            "samples_on", "cost": {"mean_usd_h", "base_usd_h", "vs_base_usd_h",
            "hours"}, "constraint_activity": [{"name", "kind", "at_lo", "at_hi",
            "active"}], "prediction_rms": {model: mean}}``. Shares are 0..1; None
            where nothing was counted.
        """
        windows = [self._window("since start", None, self.totals)]
        for h, r in zip(self.settings.windows_h, self.rings):
            windows.append(self._window(f"{h:g} h", h, r.total()))
        now = self.last_rms
        return {"samples": self.samples, "process_time_s": self.last_t_s,
                "base_cost_usd_h": self.settings.base_cost_usd_h,
                "base_cost_origin": self.settings.base_cost_origin or None,
                "cost_now_usd_h": self.last_cost_usd_h,
                "prediction_rms_now": ({} if now is None else {
                    n: (float(v) if math.isfinite(v) else None)
                    for n, v in zip(self.models, now)}),
                "windows": windows}

    # -- persistence -----------------------------------------------------------------
    def checkpoint(self) -> dict:
        """The sums and clocks, JSON-ready (arrays packed exactly)."""
        return {"variables": [list(v) for v in self.variables], "models": list(self.models),
                "windows_h": list(self.settings.windows_h), "buckets": self.settings.buckets,
                "clock_s": self.clock_s, "last_t_s": self.last_t_s, "samples": self.samples,
                "last_cost_usd_h": self.last_cost_usd_h,
                "totals": pack_array(self.totals),
                "rings": [{"index": r.index, "sums": pack_array(r.sums)} for r in self.rings]}

    def restore(self, state: dict) -> None:
        """Go on from :meth:`checkpoint`'s ``state``.

        Raises
        ------
        ValueError
            The state is for other variables, or its sums are not finite numbers >= 0 of
            the expected shape. Other windows or buckets than the settings': the totals
            go on, the trailing windows start empty.
        """
        variables = tuple((str(n), str(k)) for n, k in state["variables"])
        if variables != self.variables:
            raise ValueError("kpis: the checkpoint counts other variables")
        models = tuple(str(m) for m in state["models"])
        fields = _HEAD + 2 * self._nv + 2 * len(models)
        totals = self._sums(state["totals"], (fields,), "totals")
        clock, last_t = float(state["clock_s"]), state["last_t_s"]
        if not (math.isfinite(clock) and clock >= 0):
            raise ValueError("kpis: clock_s must be finite and >= 0")
        if last_t is not None and not math.isfinite(float(last_t)):
            raise ValueError("kpis: last_t_s must be finite")
        same = (tuple(float(h) for h in state["windows_h"]) == self.settings.windows_h
                and int(state["buckets"]) == self.settings.buckets)
        rings = []
        n = self.settings.buckets
        for h, rs in zip(self.settings.windows_h, state["rings"] if same else ()):
            r = _Ring(h * 3600.0 / n, n, fields)
            r.sums = self._sums(rs["sums"], (n, fields), "rings")
            r.index = int(rs["index"])
            rings.append(r)
        if len(rings) != len(self.settings.windows_h):
            rings = [_Ring(h * 3600.0 / n, n, fields) for h in self.settings.windows_h]
            for r in rings:
                r.index = int(clock // r.width_s)
        cost = state.get("last_cost_usd_h")
        self.models, self._fields, self.totals, self.rings = models, fields, totals, rings
        self.clock_s = clock
        self.last_t_s = None if last_t is None else float(last_t)
        self.samples = int(state.get("samples", 0))
        self.last_cost_usd_h = None if cost is None else float(cost)
        self.last_rms = None

    @staticmethod
    def _sums(obj, shape, what: str) -> np.ndarray:
        a = unpack_array(obj)
        if a.shape != shape or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError(f"kpis: {what}: expected finite sums >= 0 of shape {shape}")
        return a.copy()
