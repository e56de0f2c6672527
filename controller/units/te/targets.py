"""Steady-state targets of the TE MPC core from the active model (the layer above the MPC).

Each sample the TE controller asks :class:`CoreTargets` where the five core handles
(XMV 3, XMV 4, P_r*, T_r*, XMV 11) and the five core CVs (XMEAS 7, 11, 13, 16, 18)
should settle, and hands the answer to the MPC as its input targets, the CV references
moving with it (the plan's trajectory shifted by the targets' predicted effect). The
problem, solved by :mod:`controller.targets` (ranked limits, least relaxation)::

    min_u  c_uᵀ u + ½ Σ q_u,i (u_i - u_plan,i)²
    s.t.   y = y_plan + d + G_j (u - u_plan),
           max(u_min, u_plan - band) <= u <= min(u_max, u_plan + band, u_plan + lift),
           XMEAS 7 <= pressure_max and the operator's XMEAS 7 limits (rank 1),
           CV band (rank 2, optional)

- ``(u_plan, y_plan)``: the grade plan's handles (trimmed by the outer A-feed and
  production loops) and CVs at the end of the horizon, a steady state of the plant
  (Ricker's optimum of the grade along the plan's path);
- ``G_j``: the steady-state gain of the active model j (seed eq. 4.6 picks it) on the
  shared state (continuous form ``n' = A n + B u + f``, ``y = C n + b``:
  ``G_j = -C A⁻¹ B``, :func:`model_steady_state`);
- ``d``: the plant's offset from that steady state, ``y - y_plan - G_j Δu_lag``
  filtered over :attr:`CoreTargetSettings.offset_tau_h`, where ``Δu_lag`` is the
  handles' departure from the plan through a first-order lag of the plant's response
  (:attr:`CoreTargetSettings.response_tau_h`); without the lag the part of a move not
  yet arrived counts as a disturbance and the targets oscillate (measured: a
  2650 kPa limit at mode 0 swung the pressure 2614-2684 kPa with an 8 h period;
  with the 1 h lag 2643-2655 kPa);
- ``q_u``: the MPC's input-target weights (:class:`controller.units.te.control.
  TEMPCOptions`), so without a cost the targets are the least change of the plan in
  the MPC's own measure;
- ``c_u``: the economic term, the Downs & Vogel operating cost's gradient in the
  handles at the grade (:mod:`controller.units.te.cost_gradient`, measured on the
  plant: the five-CV models carry no cost) times
  :attr:`CoreTargetSettings.economic_weight`. The cost falls with the reactor
  pressure at every grade, so the economics lift P_r*'s target toward
  :attr:`CoreTargetSettings.economic_pressure_max` (2800 kPa) at
  :attr:`CoreTargetSettings.economic_ramp_kpa_h`, unless the pressure limit binds
  first; ``lift`` is how far they have got. They wait
  :attr:`CoreTargetSettings.economic_settle_h` after a grade change. Modes 1-3 sit at
  2800 kPa already: there the plan stands; at mode 0 (the Downs & Vogel base case,
  2705 kPa) the settled cost falls from 172.9 to 136.9 $/h (ssmpc, noise on, seed 1,
  hours 20-30; 137.7-142.9 over hours 24-48 and plant seeds 1-3), production and
  product G unchanged (22.94 against 22.95 m³/h, 53.73 against 53.72 mol% G).

The grade's specifications (production and product G/H) are equalities the structure
holds in the loops that own them: the production trim (XMEAS 17 -> the A+C feed's
target) and the G mol% ratio loop (XMEAS 40 -> the E/D ratio) integrate their errors
to zero at every steady state, whatever the core's targets; the cost's gradient is
measured with them closed, so it is the gradient along the grade's specifications,
and the targets cannot trade product for cost.

While ``y_plan + d`` meets every limit and no priced handle can move to a cheaper
value, the plan's point is the answer as it stands (no QP), so the MPC's moves are
those it makes on the plan itself. When a priced handle can move, but every handle's
own minimizer ``u_ref - c_u / q_u`` lies on or beyond one of its bounds and the CV
limits hold there by more than the solver's violation tolerance (the economic lift at
its ramp or ceiling, the usual case once the economics act), the answer is those
bounds, computed as the solver computes it from its QP's answer (no QP either). The
band keeps the targets where the models' steady-state gains agree with the plant (see
:class:`CoreTargetSettings`).

The fixed models' steady states are computed once; the adaptive model's again when
its parameters changed and :attr:`CoreTargetSettings.refresh_samples` samples have
passed (one linear solve of the shared state's order), after the previous sample's
move (:meth:`CoreTargets.prepare`) when the TE controller's bookkeeping runs there.
The checkpoint keeps the steady states that stand inside their refresh interval, so a
restored controller uses the running one's numbers until the refresh is due (computed
afresh from the restored parameters, the slow offset stood 1e-4 apart after a restart
in a grade change, ``tests/test_te_targets.py``).
A model whose steady state is not finite (a singular ``A``) gives no targets: the
plan's values are used and the decision says so (``extra["targets"]["status"] == "plan"``).

Measured limits (``tests/test_te_targets.py``): the steady state equals the fixed
point of the model's ZOH form to 1e-7 relative; a binding pressure limit gives the
handles of an independent SLSQP solve to 1e-4; a limit out of reach is relaxed by the
least violation HiGHS finds, to 1e-4 relative; a 2650 kPa limit at mode 0 (noise on)
holds the pressure at 2643-2651 kPa over hours 8-16. Solve time: that of
:class:`controller.target_solver.TargetSolver` (``ssmpc bench targets``: the same
numbers as :func:`controller.targets.solve_targets`, no problem built per sample)
when a limit binds; otherwise only the check of the sample's numbers. The sample's
arithmetic on the five handles and CVs (the offset filter, the moving fields, the two
answers without a QP) is compiled (:mod:`controller.units.te.targets_kernel`, the
same numbers bit for bit).

Measured (ssmpc, noise off and on with plant seed 1; shared 2-core AMD EPYC at the load
given; CPU time of the TE controller's targets per sample)::

    quantity                                        measured
    priced samples answered at the bounds           13,963 of 14,216 (8 runs of 40 h,
                                                    plans 0->2->3, 0, 2->0, 3->1): u, y,
                                                    cost and status bit for bit the QP's
    answered at the bounds, random problems         59 of 120 (tests/test_te_targets.py),
                                                    all bit for bit the QP's
    targets per sample, mode 0, economics on        0.322 -> 0.235 ms median of 6 x 12 h
    (before -> after these two paths, load 2.8-3.4) (best 0.263 -> 0.206 ms)
    targets / core step, 0->2->3 over 48 h          0.51-0.54 -> 0.40-0.41 (3 alternated
    (load 4.4-5.3)                                  pairs; the step's part only: the
                                                    steady state moved after the move)
    steady states prepared after the move           all 120 of 12 h (0->2->3), none in
                                                    the step
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import is_not

import numpy as np

from controller.finite_kernel import all_finite
from controller.readback import count_below, finite_vector
from controller.target_solver import TargetSolver, _cost
from controller.targets import VIOLATION_TOL, TargetProblem, TargetResult
from controller.units.te.targets_kernel import (
    AT_BOUNDS,
    NO_TARGETS,
    PLAN,
    QP,
    compile_targets_kernels,
    offset_step,
    target_fields,
)

__all__ = ["CoreTargetSettings", "CoreTargets", "model_steady_state"]

#: Fields of the target problem that stand from sample to sample (CoreTargets._check).
_STANDING_FIELDS = ("q_u", "q_y", "y_min", "y_max", "y_rank", "y_scale")


@dataclass(frozen=True)
class CoreTargetSettings:
    """Settings of the core's steady-state targets.

    Parameters
    ----------
    pressure_max : float
        Rank-1 limit of the reactor pressure (XMEAS 7) at the targets, kPa; default
        Downs & Vogel's normal operating high limit, 2895 kPa (the interlock is 3000).
    cv_band : tuple of (lo, hi) pairs, optional
        Rank-2 limits of the five core CVs (XMEAS 7, 11, 13, 16, 18) in their units;
        None = no limits beyond ``pressure_max``.
    refresh_samples : int
        Samples between two steady-state computations of an adaptive model (its
        parameters move every sample; its steady state slowly).
    band : tuple of 5 float
        How far each handle's target may move from the plan's value (% for valves,
        kPa for P_r*, degC for T_r*). Default: P_r* within 200 kPa, the others held
        at the plan. The models' steady-state gains are trusted only where the three
        fixed models agree with the plant: P_r* -> XMEAS 7 is 0.98-1.01 in every
        model (the inner pressure loop); the condenser's XMV 11 -> XMEAS 7 is
        +1.9 kPa/% at mode 0, +0.8 at mode 2 and 0.0 at mode 3 while the plant's is
        negative (shutting the condenser from 18 % raised the pressure 250 kPa in
        0.3 h), and XMV 3, XMV 4 and T_r* belong to the outer loops and the plan.
    offset_tau_h : float
        Time constant of the filter on the CVs' offset from the plan, h: long
        against the transition's dynamics (the pressure swings of a grade change
        last 0.1-0.5 h), so the offset is that of a disturbance, not of a transient.
    response_tau_h : float
        Time constant of the plant's answer to a handle's move from the plan, h.
    economics : bool
        Price the handles with the Downs & Vogel cost's gradient at the grade
        (:func:`controller.units.te.cost_gradient.cost_gradient`); off = the least
        change of the plan that meets the limits.
    economic_pressure_max : float
        Highest P_r* target the economics may ask for, kPa (default 2800, the limit of
        Ricker's optimization; the plant trips from 2895 kPa set points, see
        :mod:`~controller.units.te.cost_gradient`). A plan above it keeps its value.
    economic_weight : float
        Weight of 1 $/h against the handles' least-change weights (the MPC's
        target weights): large, so the cost decides and the limits bound it, as in an
        LP; the quadratic term only makes the answer unique.
    economic_settle_h : float
        Hours after a grade change before the economics act again, h: while the grade
        plan's path moves, the transition's own path rules (as APC suspends its LP for
        a grade change). Measured: 0 -> 2 started from the economic 2800 kPa of mode 0
        peaked at 2915 kPa, from the plan's 2705 at 2894.
    economic_ramp_kpa_h : float
        Rate at which the economics may raise P_r*'s target above the plan, kPa/h (an
        APC target's ramp rate: the economic move is a slow one, never a step into the
        plant). When they stop acting (a grade change) the target returns to the plan
        at once; the MPC's move weights make that a ramp of the handle.
    economic_lead_kpa : float
        Most the economics may ask for P_r* above the measured reactor pressure, kPa:
        the pressure follows its set point through the purge loop's lag, and a target
        that ran ahead would only shut the purge (and meet the transition guard's
        set-point tracking, 10 kPa, which then cuts it back).
    """

    pressure_max: float = 2895.0
    cv_band: tuple | None = None
    refresh_samples: int = 10
    band: tuple = (0.0, 0.0, 200.0, 0.0, 0.0)
    offset_tau_h: float = 1.0
    response_tau_h: float = 1.0
    economics: bool = True
    economic_pressure_max: float = 2800.0
    economic_weight: float = 1.0e4
    economic_settle_h: float = 12.0
    economic_ramp_kpa_h: float = 20.0
    economic_lead_kpa: float = 5.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pressure_max) and 2000.0 < self.pressure_max <= 3000.0):
            raise ValueError(f"pressure_max: must be in (2000, 3000] kPa, got "
                             f"{self.pressure_max!r}")
        if isinstance(self.refresh_samples, bool) or not isinstance(self.refresh_samples, int) \
                or self.refresh_samples < 1:
            raise ValueError(f"refresh_samples: must be an integer >= 1, got "
                             f"{self.refresh_samples!r}")
        band = np.asarray(self.band, dtype=float)
        if band.shape != (5,) or not np.isfinite(band).all() or np.any(band < 0):
            raise ValueError(f"band: five finite values >= 0, got {self.band!r}")
        for name in ("offset_tau_h", "response_tau_h"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be > 0 h, got {v!r}")
        if not isinstance(self.economics, bool):
            raise ValueError(f"economics: must be true or false, got {self.economics!r}")
        v = self.economic_pressure_max
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 2000.0 < v <= 3000.0):
            raise ValueError(f"economic_pressure_max: must be in (2000, 3000] kPa, got {v!r}")
        # (name, unit, whether 0 is allowed)
        for name, unit, zero_ok in (("economic_settle_h", " h", True),
                                    ("economic_ramp_kpa_h", " kPa/h", False),
                                    ("economic_lead_kpa", " kPa", True),
                                    ("economic_weight", "", False)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)
                    and (v >= 0 if zero_ok else v > 0)):
                raise ValueError(f"{name}: must be {'>=' if zero_ok else '>'} 0{unit}, "
                                 f"got {v!r}")
        if self.cv_band is not None:
            band = np.asarray(self.cv_band, dtype=float)
            if band.shape != (5, 2) or np.isnan(band).any() or np.any(band[:, 0] > band[:, 1]):
                raise ValueError("cv_band: five (lo, hi) pairs with lo <= hi (±inf = none)")


_P = 2  # P_r* among the core handles


def _vector(v) -> np.ndarray:
    """``v`` as a C-contiguous, writeable float64 vector (no copy when it is one)."""
    a = np.asarray(v, dtype=float)
    if a.ndim != 1 or not a.flags.carray:  # also a read-only one: the kernels' own type
        a = np.array(a.reshape(-1))
    return a


def _cheaper_within(fields: dict) -> bool:
    """Whether a priced handle could move from the plan to a cheaper value within its
    range (then the plan is not the answer even when it meets the limits)."""
    c = fields.get("cost_u")
    if c is None:
        return False
    u, lo, hi = fields["u_ref"], fields["u_min"], fields["u_max"]
    return bool(np.any(((c < 0) & (u < hi)) | ((c > 0) & (u > lo))))


def model_steady_state(ssm, j: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Steady state of model ``j`` of a :class:`controller.state_shared.StateSharedModel`:
    ``y_ss = G u + a`` for a constant input ``u``.

    At a steady state every block of the shared state is its signal times the basis's
    steady vector ``s = -Fb^-1 gb`` (eq. 3.10 with ``n' = 0``), so
    ``y = Theta_1' (u (x) s) + Theta_2' (y (x) s) + b``, i.e. ``(I - Q) y = H u + b``
    with ``H``, ``Q`` the read-outs of ``s`` through the input and output blocks of
    ``Theta_j'``: one (p, p) solve, where the continuous form's ``A x = -[B, f]`` is one
    of the shared order (the same answer; ``A`` is singular exactly when ``I - Q`` is,
    since ``F`` is Hurwitz).

    Returns
    -------
    (G, a) : ndarray (p, m), ndarray (p,)
        Gain (output units per input unit) and offset; None when ``I - Q`` is
        singular or the result is not finite.
    """
    m, p, n = ssm.m, ssm.p, ssm.n_deg
    read = ssm.theta_rows(j).reshape(p, m + p, n) @ ssm.basis.steady  # [H, Q], (p, m + p)
    lhs = -read[:, m:]
    lhs[np.diag_indices(p)] += 1.0
    rhs = np.empty((p, m + 1))
    rhs[:, :m] = read[:, :m]
    rhs[:, m] = ssm.bias(j)
    try:
        X = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        return None
    G, a = X[:, :m].copy(), X[:, m].copy()
    if not (all_finite(G) and all_finite(a)):
        return None
    return G, a


def _standing_steady_state(entry, refresh_samples: int):
    """``(model, age, (G, a) or None)`` of a checkpoint's standing steady state, or None
    when the entry is damaged (not a mapping, a model or age that is not a count, an
    age beyond the refresh interval, ``G`` not 5 x 5 finite numbers or ``a`` not 5)."""
    if not isinstance(entry, dict):
        return None
    j, age = entry.get("model"), entry.get("age")
    if not (count_below(j) and count_below(age, refresh_samples)):
        return None
    gain, bias = entry.get("gain"), entry.get("bias")
    if gain is None and bias is None:
        return j, age, None
    try:
        G = finite_vector(np.ravel(np.asarray(gain, dtype=float)), 25, "gain").reshape(5, 5)
        a = finite_vector(bias, 5, "bias")
    except (TypeError, ValueError):
        return None
    return j, age, (G, a)


class CoreTargets:
    """Steady-state targets of the TE core on the active model (module docstring).

    Parameters
    ----------
    q_u : array_like (5,)
        Weights of the handles toward the plan, per (% or kPa or degC)^2 (> 0).
    q_y : array_like (5,)
        Weights of the CVs toward the plan, per CV unit^2 (>= 0).
    y_scale : array_like (5,)
        CV scales for comparing relaxations.
    u_min, u_max : array_like (5,)
        Handle ranges.
    settings : CoreTargetSettings, optional
    cv_names, mv_names : tuple of str
    """

    def __init__(self, q_u, q_y, y_scale, u_min, u_max,
                 settings: CoreTargetSettings | None = None,
                 cv_names: tuple[str, ...] = (), mv_names: tuple[str, ...] = ()) -> None:
        self.settings = settings or CoreTargetSettings()
        self.q_u = np.asarray(q_u, dtype=float).reshape(-1)
        self.q_y = np.asarray(q_y, dtype=float).reshape(-1)
        self.y_scale = np.asarray(y_scale, dtype=float).reshape(-1)
        self.u_min = np.asarray(u_min, dtype=float).reshape(-1)
        self.u_max = np.asarray(u_max, dtype=float).reshape(-1)
        self.cv_names, self.mv_names = tuple(cv_names), tuple(mv_names)
        self.band = np.asarray(self.settings.band, dtype=float)
        self._solver = TargetSolver(5, 5, self.cv_names, self.mv_names)
        y_min = np.full(5, -np.inf)
        y_max = np.full(5, np.inf)
        rank = np.full(5, 2)
        if self.settings.cv_band is not None:
            band = np.asarray(self.settings.cv_band, dtype=float)
            y_min, y_max = band[:, 0].copy(), band[:, 1].copy()
        if self.settings.pressure_max < y_max[0]:
            y_max[0] = self.settings.pressure_max
        rank[0] = 1
        self.y_min, self.y_max, self.y_rank = y_min, y_max, rank
        self._tuned = (y_min.copy(), y_max.copy(), rank.copy())
        # model -> (theta the steady state was computed from, the sample it was computed
        # at, (G, a) or None); samples are counted by observe, once per sample
        self._steady: dict[int, tuple] = {}
        self._n = 0
        self.last: TargetResult | None = None
        #: slow offset of the CVs from the plan (5,), None before the first sample
        self.offset: np.ndarray | None = None
        #: the handles' departure from the plan through the plant's response lag (5,)
        self.du_lagged = np.zeros(5)
        #: how far above the plan the economics may take P_r*'s target now, kPa (ramped)
        self.econ_lift = 0.0
        self._econ_cost: np.ndarray | None = None  # the last gradient the economics used
        self._dt_h = 0.0
        self._applied_p = math.nan  # P_r* the plant has, kPa (observe)
        self._pressure = math.nan  # the measured reactor pressure, kPa (observe)
        # the standing fields at the last full check of the solver's numbers (_check)
        self._checked: tuple | None = None
        self._gains: tuple | None = None  # (dt_h, settings, lag gain, offset gain)
        # (model, sample, theta, steady state) computed after the previous move (prepare)
        self._ahead: tuple | None = None
        self._no_cost = np.zeros(5)  # the kernel's cost argument while unpriced (unread)
        compile_targets_kernels()  # not in the first sample
        # (read-only gradient, settings, checked gradient or None, it times the weight)
        self._priced: tuple | None = None
        self._tol_cache: tuple | None = None  # (y_scale, VIOLATION_TOL * y_scale)
        self._q_y_any: tuple | None = None  # (q_y, any of it)

    def steady_state(self, ssm, j: int):
        """(G, a) of model j, cached while its parameters stand (adaptive models:
        refreshed at most every ``refresh_samples`` samples); None if it has none."""
        ahead, self._ahead = self._ahead, None
        if (ahead is not None and ahead[0] == j and ahead[1] == self._n
                and ssm.model(j).theta is ahead[2]):
            # what the lines below compute now, from the same parameters (prepare)
            self._steady[j] = (ahead[2], self._n, ahead[3])
            return ahead[3]
        cached = self._steady.get(j)
        if cached is not None:
            th, made, ss = cached
            # inside the refresh interval an adaptive model's steady state stands: no need
            # to read its parameters (ssm.model builds them after every adaptation)
            if (self._n - made < self.settings.refresh_samples
                    and ssm.kind(j) != "fixed"):
                return ss
            theta = ssm.model(j).theta
            if th is theta:
                return ss
        else:
            theta = ssm.model(j).theta
        ss = model_steady_state(ssm, j)
        self._steady[j] = (theta, self._n, ss)
        return ss

    def prepare(self, ssm, j: int) -> None:
        """After the move: the steady state of model ``j`` (the active one) that the next
        sample's :meth:`observe` would compute, computed now when it is due (a new model,
        or an adaptive model's refresh with its parameters moved); off the path from the
        measurement to the move. The next sample takes it only if ``j`` is still the
        model and its parameters are the very ones used here."""
        cached = self._steady.get(j)
        if (cached is not None and ssm.kind(j) != "fixed"
                and self._n + 1 - cached[1] < self.settings.refresh_samples):
            return
        theta = ssm.model(j).theta
        if cached is not None and cached[0] is theta:
            return
        self._ahead = (j, self._n + 1, theta, model_steady_state(ssm, j))

    def observe(self, ssm, j: int, y, u_applied, y_plan_now, u_plan_now, dt_h: float) -> None:
        """Take in one sample: measured CVs ``y`` (5,) under the applied handles
        ``u_applied`` (5,), and the plan's CVs and handles at the same time
        (``y_plan_now``, ``u_plan_now``, (5,) each). Updates the slow offset ``d`` of the
        plant from model j's steady state about the plan, ``y - y_plan - G_j (u - u_plan)``
        (first-order filter, :attr:`CoreTargetSettings.offset_tau_h`). Non-finite values
        are skipped (``d`` holds)."""
        self._n += 1
        self._dt_h = float(dt_h) if math.isfinite(dt_h) and dt_h > 0 else 0.0
        y, u_applied = _vector(y), _vector(u_applied)
        self._applied_p = float(u_applied[_P])
        self._pressure = float(y[0])
        ss = self.steady_state(ssm, j)
        if ss is None:
            return
        y_plan_now, u_plan_now = _vector(y_plan_now), _vector(u_plan_now)
        if self.offset is None:
            if not all_finite(np.concatenate((y, u_applied, y_plan_now, u_plan_now))):
                return
            self.offset = np.zeros(5)  # the plan is the steady state until shown otherwise
            self.du_lagged = np.zeros(5)
        # the plant answers a handle's move from the plan with a lag: the offset compares
        # the measurement with the lagged steady-state answer, else it would count the
        # part not yet arrived as a disturbance (a slow oscillation of the targets);
        # one compiled call (controller.units.te.targets_kernel), nothing changed when an
        # input is not finite
        lag, alpha = self._filter_gains(float(dt_h))
        offset_step(ss[0], y, u_applied, y_plan_now, u_plan_now, self.du_lagged,
                    self.offset, lag, alpha)

    def _filter_gains(self, dt_h: float) -> tuple[float, float]:
        """``1 - exp(-dt / tau)`` of the response lag and of the offset filter for a
        sample of ``dt_h`` (h), kept for the last ``dt_h`` and settings (the same every
        sample)."""
        s, cached = self.settings, self._gains
        if cached is None or cached[0] != dt_h or cached[1] is not s:
            cached = self._gains = (dt_h, s, 1.0 - math.exp(-dt_h / s.response_tau_h),
                                    1.0 - math.exp(-dt_h / s.offset_tau_h))
        return cached[2], cached[3]

    def _fields(self, ssm, j: int, u_plan, y_plan) -> dict | None:
        """The fields of :meth:`problem` (those of :class:`TargetProblem` but the
        names), or None."""
        ss = self.steady_state(ssm, j)
        if ss is None or not (all_finite(np.asarray(u_plan, dtype=float))
                              and all_finite(np.asarray(y_plan, dtype=float))):
            return None
        u_ref = np.minimum(np.maximum(u_plan, self.u_min), self.u_max)
        d = np.zeros(5) if self.offset is None else self.offset
        u_lo = np.maximum(self.u_min, u_ref - self.band)
        u_hi = np.minimum(self.u_max, u_ref + self.band)
        fields = dict(gain=ss[0], u0=u_ref, y0=y_plan, bias=d, u_min=u_lo, u_max=u_hi,
                      q_u=self.q_u, q_y=self.q_y, u_ref=u_ref, y_ref=y_plan,
                      y_min=self.y_min, y_max=self.y_max, y_rank=self.y_rank,
                      y_scale=self.y_scale)
        c = self._econ_cost
        if c is not None:
            # the economics may raise P_r* only as far as the lift has ramped (toward
            # the ceiling; a plan above it keeps its value); the safety limit on
            # XMEAS 7 stays a CV limit
            u_hi[_P] = min(u_hi[_P], u_ref[_P] + self.econ_lift)
            fields["cost_u"] = c * self.settings.economic_weight
        return fields

    def _ramp_economics(self, cost_u, u_plan_p: float) -> None:
        """One sample of the economic lift: up toward the ceiling at
        :attr:`CoreTargetSettings.economic_ramp_kpa_h` while a gradient is given
        (:attr:`CoreTargetSettings.economics` on), never more than one ramp step
        above the P_r* applied nor :attr:`CoreTargetSettings.economic_lead_kpa` above
        the measured pressure (:meth:`observe`), at once to the plan otherwise (a
        grade change under way) or when the ceiling comes down."""
        st = self.settings
        c = None
        if st.economics and cost_u is not None:
            known = self._priced
            if known is not None and known[0] is cost_u and known[1] is st:
                c = known[2]  # the same read-only gradient as the last sample's
            else:
                c = np.asarray(cost_u, dtype=float).reshape(5)
                if not (np.isfinite(c).all() and c[_P] < 0):
                    c = None  # only a cost falling with the pressure is priced
                if isinstance(cost_u, np.ndarray) and not cost_u.flags.writeable:
                    # cost_gradient's arrays, one per grade: checked and weighted once
                    self._priced = (cost_u, st, c,
                                    None if c is None else c * st.economic_weight)
        self._econ_cost = c
        if c is None:  # a grade change's path rules: back to the plan (the MPC's move
            self.econ_lift = 0.0  # weights smooth the way)
            return
        want = max(st.economic_pressure_max - u_plan_p, 0.0) if math.isfinite(u_plan_p) \
            else 0.0
        step = st.economic_ramp_kpa_h * self._dt_h
        # never more than a step ahead of the handle the plant has: while the
        # controller is WARM or OFF (moves held) the lift tracks the held P_r*, so the
        # return to ON is bumpless
        ahead = max(self._applied_p - u_plan_p, 0.0) + step \
            if math.isfinite(self._applied_p) else math.inf
        # it rises no further above the measured pressure than the lead (a pressure that
        # falls later does not pull it down: the transition guard's tracking does that)
        lead = self._pressure + st.economic_lead_kpa - u_plan_p \
            if math.isfinite(self._pressure) else math.inf
        cap = min(want, ahead)
        if min(cap, lead) > self.econ_lift:
            self.econ_lift = min(self.econ_lift + step, cap, lead)
        else:
            self.econ_lift = max(0.0, min(self.econ_lift, cap))

    def problem(self, ssm, j: int, u_plan, y_plan) -> TargetProblem | None:
        """The target problem of model ``j`` around the plan's end point: handles
        ``u_plan`` (5,), CVs ``y_plan`` (5,), a steady state of the plant, moved by the
        observed offset ``d`` (:meth:`observe`): ``y = y_plan + d + G_j (u - u_plan)``.
        The economic term as :meth:`solve` last left it (:attr:`econ_lift`). None
        when the model has no steady state or an input is not finite."""
        fields = self._fields(ssm, j, u_plan, y_plan)
        if fields is None:
            return None
        return TargetProblem(**fields, cv_names=self.cv_names, mv_names=self.mv_names)

    def set_operator_limits(self, y_min=None, y_max=None) -> None:
        """Operator limits of the five CVs (5,) each, ±inf or NaN = none; they act at
        the targets' rank 1 inside the tuned limits. No argument: the tuned limits."""
        lo, hi, rank = self._tuned
        op = np.zeros(5, dtype=bool)  # CVs with an operator limit: rank 1
        if y_min is not None:
            v = np.asarray(y_min, dtype=float).reshape(5)
            op |= np.isfinite(v)
            lo = np.maximum(lo, np.where(np.isnan(v), -np.inf, v))
        if y_max is not None:
            v = np.asarray(y_max, dtype=float).reshape(5)
            op |= np.isfinite(v)
            hi = np.minimum(hi, np.where(np.isnan(v), np.inf, v))
        self.y_min, self.y_max = lo, hi
        self.y_rank = np.where(op, 1, rank)

    def solve(self, ssm, j: int, u_plan, y_plan, cost_u=None) -> TargetResult | None:
        """Targets for this sample (see :meth:`problem`); None = use the plan's values.
        When the plan's point meets every limit and no priced handle can move to a
        cheaper value within its range, it is the answer as it stands (no QP: the
        least change of the plan that meets the limits is no change). Solved by
        :class:`~controller.target_solver.TargetSolver` (the numbers of
        ``solve_targets(self.problem(...))``).

        ``cost_u`` (5,): the operating cost's gradient in the handles at the grade, $/h
        per unit (:func:`~controller.units.te.cost_gradient.cost_gradient`), None while
        the economics wait (a grade change settling); used when
        :attr:`CoreTargetSettings.economics` is on, P_r*'s part only, through the
        ramped :attr:`econ_lift`."""
        u_plan, y_plan = _vector(u_plan), _vector(y_plan)
        self._ramp_economics(cost_u, float(u_plan[_P]))
        if self._weighs_cvs():  # CV weights: always the QP
            fields = self._fields(ssm, j, u_plan, y_plan)
            if fields is None:
                self.last = None
                return None
            return self._solve_qp(fields)
        ss = self.steady_state(ssm, j)
        if ss is None:
            self.last = None
            return None
        # the fields that move every sample and the two answers without a QP, in one
        # compiled call (controller.units.te.targets_kernel; the numbers of _fields,
        # _cheaper_within and _at_bounds)
        d = np.zeros(5) if self.offset is None else self.offset
        c = self._econ_cost
        priced = c is not None
        if not priced:
            cost = self._no_cost
        elif self._priced is not None and self._priced[2] is c:
            cost = self._priced[3]  # c * economic_weight, kept with the gradient
        else:
            cost = c * self.settings.economic_weight
        outcome, cheaper, ok, u_ref, u_lo, u_hi, u, y = target_fields(
            ss[0], u_plan, y_plan, d, self.u_min, self.u_max, self.band, priced, cost,
            float(self.econ_lift), _P, self.q_u, self.y_min, self.y_max, self._tol())
        if outcome == NO_TARGETS:
            self.last = None
            return None
        def fields() -> dict:  # the problem's fields (_fields), for a full check or the QP
            out = dict(gain=ss[0], u0=u_ref, y0=y_plan, bias=d, u_min=u_lo, u_max=u_hi,
                       q_u=self.q_u, q_y=self.q_y, u_ref=u_ref, y_ref=y_plan,
                       y_min=self.y_min, y_max=self.y_max, y_rank=self.y_rank,
                       y_scale=self.y_scale)
            if priced:
                out["cost_u"] = cost
            return out

        if outcome != QP or cheaper:  # the numbers a QP would refuse (_check)
            standing = (self.q_u, self.q_y, self.y_min, self.y_max, self.y_rank,
                        self.y_scale)  # the order of _STANDING_FIELDS
            last = self._checked
            # identity, element by element, in C (a generator costs ~0.7 µs a sample)
            if last is None or any(map(is_not, standing, last)):
                self._solver.check(**fields())
                self._checked = standing
            elif not ok:
                self._solver.check(**fields())  # raises, naming the field
        if outcome == PLAN:
            self.last = TargetResult("optimal", u, y, (), 0.0, 0)
            return self.last
        if outcome == AT_BOUNDS:
            self.last = TargetResult("optimal", u, y, (),
                                     _cost(u, y, self.q_u, u_ref, y_plan, cost, None, None), 0)
            return self.last
        return self._solve_qp(fields())

    def _solve_qp(self, fields: dict) -> TargetResult | None:
        res = self._solver.solve(**fields)
        self.last = None if res.status == "failed" else res
        return self.last

    def _weighs_cvs(self) -> bool:
        """Whether any CV has a weight toward the plan (``q_y``), kept while :attr:`q_y` is
        the same array (a new one is read again; the weights are settings, not written
        in place)."""
        cached = self._q_y_any
        if cached is None or cached[0] is not self.q_y:
            cached = self._q_y_any = (self.q_y, bool(self.q_y.any()))
        return cached[1]

    def _tol(self) -> np.ndarray:
        """The solver's violation tolerance in CV units (:data:`VIOLATION_TOL` times the
        CV scales), kept while the scales stand."""
        cached = self._tol_cache
        if cached is None or cached[0] is not self.y_scale:
            cached = self._tol_cache = (self.y_scale, VIOLATION_TOL * self.y_scale)
        return cached[1]

    def _at_bounds(self, fields: dict) -> TargetResult | None:
        """The answer of a priced problem without its QP when it is one of the box: every
        handle's own minimizer ``u_ref - c_u / q_u`` (no CV weights) lies on or beyond
        one of its bounds, and the CV limits hold at those bounds by more than the
        solver's violation tolerance (so no limit is active and none is relaxed). The
        optimum is then those bounds, and u, y and the cost are computed as
        :meth:`TargetSolver.solve` computes them from its QP's answer (the same numbers
        bit for bit: random problems in ``tests/test_te_targets.py``, eight TE runs in
        the module's table). None: the QP decides."""
        self._check(fields)  # the numbers a QP would refuse (q_u > 0 among them)
        c, q, r = fields["cost_u"], fields["q_u"], fields["u_ref"]
        lo, hi = fields["u_min"], fields["u_max"]
        x = -(c - q * r) / q  # the solver's linear term f = c_u - q_u u_ref, x = -f / q_u
        up, down = x >= hi, x <= lo
        if not (up | down).all():
            return None
        u = np.where(up, hi, lo)
        G = fields["gain"]
        y = (fields["y0"] + fields["bias"]) - G @ fields["u0"] + G @ u
        tol = VIOLATION_TOL * self.y_scale
        if not ((y <= self.y_max - tol).all() and (y >= self.y_min + tol).all()):
            return None
        return TargetResult("optimal", u, y, (),
                            _cost(u, y, q, r, fields["y_ref"], c, None, None), 0)

    def _check(self, fields: dict) -> None:
        """:meth:`TargetSolver.check` of the sample's fields (ValueError on numbers a QP
        would refuse). In full when the fields that stand from sample to sample (weights,
        scales, CV limits and ranks) are other objects than at the last full check, else
        what the solver checks of the fields that change every sample: finite and
        ``u_min <= u_max`` (the plan's point outside that is refused in full)."""
        standing = tuple(fields[k] for k in _STANDING_FIELDS)
        last = self._checked
        if last is None or any(a is not b for a, b in zip(standing, last, strict=True)):
            self._solver.check(**fields)
            self._checked = standing
            return
        lo, hi = fields["u_min"], fields["u_max"]
        moving = np.concatenate((fields["gain"].ravel(), fields["u0"], fields["y0"],
                                 fields["bias"], lo, hi))
        if not (all_finite(moving) and (lo <= hi).all()):
            self._solver.check(**fields)  # raises, naming the field

    def checkpoint(self) -> dict:
        """What a restart needs to go on (JSON-serialisable). Besides the filters, the
        steady states that stand inside their refresh interval (``steady``: model, age
        in samples, ``G`` and ``a``; the adaptive model's, computed from parameters
        that have moved since), so that a restored controller uses the very numbers the
        running one would until their refresh is due."""
        steady = []
        for j, (_, made, ss) in sorted(self._steady.items()):
            age = self._n - made
            if age < self.settings.refresh_samples:
                steady.append({"model": int(j), "age": int(age),
                               "gain": None if ss is None else ss[0].tolist(),
                               "bias": None if ss is None else ss[1].tolist()})
        return {"offset": None if self.offset is None else self.offset.tolist(),
                "du_lagged": self.du_lagged.tolist(), "econ_lift": float(self.econ_lift),
                "steady": steady}

    def restore(self, state: dict) -> None:
        off = state.get("offset")
        # copies: the offset filter writes into them
        self.offset = None if off is None else np.array(off, dtype=float).reshape(5)
        self.du_lagged = np.array(state.get("du_lagged", np.zeros(5)), dtype=float).reshape(5)
        # the gradient the lift prices comes with the next sample (solve)
        lift = float(state.get("econ_lift", 0.0) or 0.0)
        self.econ_lift = lift if math.isfinite(lift) and lift > 0.0 else 0.0
        # the standing steady states; one absent or damaged is computed again from the
        # restored model's parameters at the next sample (a checkpoint without them)
        self._steady, self._n, self._ahead = {}, 0, None
        entries = state.get("steady")
        for e in entries if isinstance(entries, list) else ():
            kept = _standing_steady_state(e, self.settings.refresh_samples)
            if kept is not None:
                j, age, ss = kept
                self._steady[j] = (None, -age, ss)  # no parameters: refreshed when due
