"""Mixed-sensitivity H-infinity control on the selected model (seed §5.2).

The seed's generalized plant (eq. 5.17) has inputs ``(w, r, u)`` and outputs
``(W2 u, W1 e, e)`` with ``e = r - (M u + w)``; the closed loop (eq. 5.19) is
``[[-W2 K S, W2 K S], [-W1 S, W1 S]]`` with ``S = 1/(1 + M K)``. Minimizing its
H-infinity norm is the standard mixed-sensitivity problem ``|| [W1 S; W2 K S] ||``,
solved here with python-control's ``augw`` and SLICOT (``sb10ad`` for the
optimal level, then ``sb10fd`` at ``gamma_factor`` times it: the optimal central
controller of this problem is nearly singular, with poles at -1e7 and beyond,
while a slightly suboptimal one is well conditioned).

**Integral action.** ``M`` is a deviation model but the loop runs in absolute
units about a moving operating point, so any steady error is an offset that the
controller must remove. The seed's ``W1 = (s + a) / (2 (s + eps))`` with a small
``eps`` forces ``|S(0)| ~ 2 eps / a`` but not zero; the synthesized ``K``
contains the weight's pole ``-eps``. With ``integral=True`` the implemented
controller is ``K (s + eps) / s``: the pole at ``-eps`` is exchanged for an
exact integrator (the loop above ``eps`` is unchanged), so steady offsets vanish.
The closed loop with the design model is checked after the change.

**Operating point.** The controller acts on ``e = r - y`` in absolute units and
produces an increment: ``u = u_hold + K_d(e)``; ``u_hold`` is set at every
controller change so that ``u`` is continuous (bumpless).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.linalg

if TYPE_CHECKING:  # python-control pulls in scipy.signal and matplotlib (~2 s at start-up):
    import control as ct  # imported where a design is made, not by every node process

__all__ = [
    "HInfWeights",
    "HInfDesign",
    "DiscreteController",
    "equilibrium_state",
    "HInfSynthesisError",
    "synthesize",
    "siso_model_tf",
    "HInfLaw",
]


class HInfSynthesisError(ValueError):
    """Synthesis failed (model not stabilizable, weights inadmissible, unstable loop)."""


def _poly(coeffs, field: str) -> tuple[float, ...]:
    c = tuple(float(v) for v in np.atleast_1d(np.asarray(coeffs, dtype=float)))
    if not c or not all(math.isfinite(v) for v in c) or c[0] == 0:
        raise ValueError(f"{field}: need finite polynomial coefficients (highest power first, "
                         f"leading one nonzero), got {coeffs!r}")
    return c


@dataclass(frozen=True)
class HInfWeights:
    """Weights of the mixed-sensitivity problem, polynomials highest power first.

    Parameters
    ----------
    w1_num, w1_den : sequence of float
        Performance weight ``W1`` on the sensitivity S (proper, stable).
    w2_num, w2_den : sequence of float
        Robustness/control weight ``W2`` on ``K S`` (proper, stable).
    gamma_factor : float
        Synthesize at ``gamma_factor * gamma_opt`` (>= 1; 1 means optimal).
    integral : bool
        Replace W1's slowest pole in K by an exact integrator (see module notes).
    """

    w1_num: tuple[float, ...] = (1.0, 1.0)
    w1_den: tuple[float, ...] = (2.0, 0.04)
    w2_num: tuple[float, ...] = (1.0, 25.0)
    w2_den: tuple[float, ...] = (1.0, 6000.0)
    gamma_factor: float = 1.2
    integral: bool = True

    def __post_init__(self) -> None:
        for name in ("w1_num", "w1_den", "w2_num", "w2_den"):
            object.__setattr__(self, name, _poly(getattr(self, name), name))
        for num, den in (("w1_num", "w1_den"), ("w2_num", "w2_den")):
            if len(getattr(self, num)) > len(getattr(self, den)):
                raise ValueError(f"{num}: weight must be proper (degree <= that of {den})")
            if np.any(np.roots(getattr(self, den)).real >= 0):
                raise ValueError(f"{den}: weight must be stable (poles in the open left half)")
        if not (math.isfinite(self.gamma_factor) and self.gamma_factor >= 1.0):
            raise ValueError(f"gamma_factor: must be >= 1, got {self.gamma_factor!r}")

    @classmethod
    def seed_cstr(cls, a: float = 1.0, c: float = 0.1, **kw) -> HInfWeights:
        """Seed §5.2.1: ``W1 = (s + a)/(2(s + 0.02))`` (``a`` lost in OCR; 1 chosen),
        ``W2 = c (s + 25)/(s + 6000)`` (``c`` lost; 0.1 chosen)."""
        return cls((1.0, a), (2.0, 0.04), (c, 25.0 * c), (1.0, 6000.0), **kw)

    @classmethod
    def seed_bioreactor(cls, c: float = 0.1, *, eps: float = 0.02, **kw) -> HInfWeights:
        """Seed §5.2.2: ``W1 = (s + 3.5)/(2(s + 3.2))``, ``W2 = c (s + 25)/(s + 6000)``.

        The printed W1 is almost flat (|S(0)| <= 1.83 only), so it cannot make
        the loop track; by default its pole is moved to ``-eps`` (the CSTR's
        0.02) which gives integral action. ``eps=3.2`` restores the printed W1.
        """
        return cls((1.0, 3.5), (2.0, 2.0 * eps), (c, 25.0 * c), (1.0, 6000.0), **kw)

    def w1(self) -> ct.TransferFunction:
        import control as ct

        return ct.tf(self.w1_num, self.w1_den)

    def w2(self) -> ct.TransferFunction:
        import control as ct

        return ct.tf(self.w2_num, self.w2_den)

    def as_dict(self) -> dict[str, Any]:
        return {"w1_num": list(self.w1_num), "w1_den": list(self.w1_den),
                "w2_num": list(self.w2_num), "w2_den": list(self.w2_den),
                "gamma_factor": self.gamma_factor, "integral": self.integral}


def siso_model_tf(theta1, theta2, a) -> tuple[np.ndarray, np.ndarray]:
    """Transfer function of a SISO state-shared model from its parameters (eq. 3.16).

    ``theta1`` are the numerator coefficients and ``theta2 = a - d``, all lowest
    power first, so ``M(s) = sum theta1_i s^(i-1) / (s^n + sum (a_i - theta2_i) s^(i-1))``.

    Returns
    -------
    num, den : ndarray
        Coefficients highest power first (``den`` monic, length n+1).
    """
    t1 = np.asarray(theta1, dtype=float).reshape(-1)
    t2 = np.asarray(theta2, dtype=float).reshape(-1)
    a = np.asarray(a, dtype=float).reshape(-1)
    if not (t1.size == t2.size == a.size):
        raise ValueError("theta1, theta2, a: must have the same length n")
    d = a - t2
    return t1[::-1].copy(), np.concatenate(([1.0], d[::-1]))


@dataclass(frozen=True)
class DiscreteController:
    """``x(k+1) = A x(k) + B e(k)``, ``du(k) = C x(k) + D e(k)`` (SISO or MIMO).

    Shapes: A (nk, nk), B (nk, ne), C (nu, nk), D (nu, ne).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float

    @property
    def nk(self) -> int:
        return self.A.shape[0]

    def as_dict(self) -> dict[str, Any]:
        return {"A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                "D": self.D.tolist(), "dt": self.dt}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DiscreteController:
        return cls(*(np.atleast_2d(np.asarray(d[k], dtype=float)) for k in "ABCD"),
                   float(d["dt"]))


@dataclass(frozen=True)
class HInfDesign:
    """One synthesis result.

    Attributes
    ----------
    K : control.StateSpace
        Continuous controller as implemented (with the integrator when requested).
    K_hinf : control.StateSpace
        The H-infinity controller itself.
    gamma_opt, gamma : float
        Optimal level and the level synthesized at.
    closed_loop_poles : ndarray
        Poles of the continuous loop with the design model (with K).
    discrete : DiscreteController
        ZOH discretization of K for the sample time.
    max_discrete_pole : float
        Largest |pole| of the sampled loop (design model ZOH + discrete K); < 1 = stable.
    """

    K: ct.StateSpace
    K_hinf: ct.StateSpace
    gamma_opt: float
    gamma: float
    closed_loop_poles: np.ndarray
    discrete: DiscreteController
    max_discrete_pole: float
    integral: bool = field(default=True)


def _zoh(A, B, dt):
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * dt
    M[:n, n:] = B * dt
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n:]


def synthesize(num, den, weights: HInfWeights, dt: float) -> HInfDesign:
    """Mixed-sensitivity H-infinity controller for the SISO model ``num/den``.

    Parameters
    ----------
    num, den : array_like
        Model ``M(s)`` (deviation variables), highest power first; strictly proper.
    weights : HInfWeights
    dt : float
        Sample time for the discrete controller.

    Raises
    ------
    HInfSynthesisError
        When the problem has no admissible controller or the loop is not stable.
    """
    import control as ct
    from slycot import sb10fd

    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=float)), "f")
    den = np.atleast_1d(np.asarray(den, dtype=float))
    if num.size == 0 or not (np.isfinite(num).all() and np.isfinite(den).all()):
        raise HInfSynthesisError("model: numerator is zero or the model is not finite")
    if num.size >= den.size:
        raise HInfSynthesisError("model: must be strictly proper")
    M = ct.ss(ct.tf(num, den))
    with warnings.catch_warnings():  # augw uses python-control's deprecated connect()
        warnings.simplefilter("ignore", FutureWarning)
        P = ct.augw(M, weights.w1(), weights.w2())
    gamma_opt = _optimal_gamma(P, weights)
    gamma = weights.gamma_factor * gamma_opt
    try:
        Ak, Bk, Ck, Dk, _ = sb10fd(P.nstates, P.ninputs, P.noutputs, 1, 1, gamma,
                                   P.A, P.B, P.C, P.D)
    except Exception as exc:  # slycot raises its own error types
        raise HInfSynthesisError(f"synthesis failed at gamma = {gamma:.4g}: {exc}") from exc
    K_hinf = ct.ss(Ak, Bk, Ck, Dk)
    K = K_hinf
    if weights.integral:
        eps = float(np.min(np.abs(np.roots(weights.w1_den))))
        # K (s + eps)/s = K (1 + eps/s): integrate e, feed e + eps * int(e) to K
        K = K_hinf * ct.tf([1.0, eps], [1.0, 0.0])
        K = ct.ss(K)
    L = ct.feedback(M * K, 1)
    cl_poles = np.asarray(L.poles())
    if not np.all(cl_poles.real < 0):
        raise HInfSynthesisError(
            f"closed loop with the design model is unstable (max Re = {cl_poles.real.max():.3g})")
    Ad, Bd = _zoh(np.asarray(K.A), np.asarray(K.B), dt)
    disc = DiscreteController(Ad, Bd, np.asarray(K.C, dtype=float),
                              np.asarray(K.D, dtype=float), float(dt))
    max_pole = _sampled_loop_radius(M, disc)
    if not max_pole < 1.0:
        raise HInfSynthesisError(
            f"sampled loop with the design model is unstable (|pole| = {max_pole:.4g}); "
            f"reduce dt or the controller bandwidth")
    return HInfDesign(K, K_hinf, gamma_opt, gamma, cl_poles, disc, max_pole, weights.integral)


def _admissible(P, gamma: float) -> bool:
    from slycot import sb10fd

    try:
        sb10fd(P.nstates, P.ninputs, P.noutputs, 1, 1, gamma, P.A, P.B, P.C, P.D)
    except Exception:
        return False
    return True


def _optimal_gamma(P, weights: HInfWeights, rtol: float = 1e-3, gamma_max: float = 1e6) -> float:
    """Smallest admissible gamma by bisection with SLICOT ``sb10fd`` (0.1 ms per try).

    The lower end starts at ``|W1(inf)|``: S -> 1 at high frequency for a strictly
    proper model, so no controller does better. (``sb10ad``'s own gamma iteration
    from a huge start costs ~100 ms here, which matters when re-synthesizing.)
    """
    lo = abs(weights.w1_num[0] / weights.w1_den[0]) if len(weights.w1_num) == len(
        weights.w1_den) else 0.0
    hi = max(2.0 * lo, 1.0)
    while not _admissible(P, hi):
        hi *= 4.0
        if hi > gamma_max:
            raise HInfSynthesisError(f"no admissible controller for gamma <= {gamma_max:g}")
    if _admissible(P, lo * (1 + rtol)) if lo > 0 else False:
        return lo * (1 + rtol)
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi)
        if _admissible(P, mid):
            hi = mid
        else:
            lo = mid
    return hi


def _sampled_loop_radius(M: ct.StateSpace, K: DiscreteController) -> float:
    """Spectral radius of the loop: ZOH-sampled model, K on the sampled error e = -y."""
    Ap, Bp = _zoh(np.asarray(M.A), np.asarray(M.B), K.dt)
    Cp = np.asarray(M.C)
    # x(k+1) = Ap x + Bp u, xk(k+1) = A xk + B e, u = C xk + D e, e = -Cp x
    top = np.hstack([Ap - Bp @ K.D @ Cp, Bp @ K.C])
    bot = np.hstack([-K.B @ Cp, K.A])
    return float(np.max(np.abs(np.linalg.eigvals(np.vstack([top, bot])))))


def _integrator_projector(A: np.ndarray, tol: float = 1e-8) -> np.ndarray:
    """Spectral projector onto the eigenvalue-1 modes of ``A`` (integrators), (nk, nk)."""
    lam, V = np.linalg.eig(A)
    idx = np.flatnonzero(np.abs(lam - 1.0) < tol)
    if idx.size == 0:
        return np.zeros_like(A)
    W = np.linalg.inv(V)
    return np.real(V[:, idx] @ W[idx, :])


def equilibrium_state(ctrl: DiscreteController, e: float, slope: float = 0.0,
                      tol: float = 1e-8) -> tuple[np.ndarray, np.ndarray]:
    """Controller state on its trajectory for the error ramp ``e_k = e + k slope``.

    Used to start a controller without an error history (bumpless take-over of a held
    move). With ``P`` the spectral projector onto the integrators (eigenvalue 1 of A),
    ``x_k = a + k b + k (k - 1)/2 c`` satisfies ``x_(k+1) = A x_k + B e_k`` for every k
    when ``c = P B slope``, ``(I - A) b = (I - P) B slope`` with ``P b = P B e`` and
    ``(I - A) a = (I - P) (B e - b)``: every mode that settles is on its trajectory,
    every integrator integrates the error. An integrator's level is left at zero (the
    law's ``u_hold`` absorbs the output offset).

    Parameters
    ----------
    ctrl : DiscreteController
        SISO controller, A of shape (nk, nk), B of shape (nk, 1).
    e : float
        Tracking error ``r - y`` at this sample (output units).
    slope : float
        Change of the error per sample (output units per sample).
    tol : float
        Distance from 1 within which an eigenvalue of A counts as an integrator.

    Returns
    -------
    a, b : ndarray, shape (nk,)
        The state at this sample and its change to the next sample.
    """
    A, B = ctrl.A, ctrl.B[:, 0]
    P = _integrator_projector(A, tol)
    Q = np.eye(ctrl.nk) - P
    M = np.eye(ctrl.nk) - A
    b_set, *_ = np.linalg.lstsq(M, Q @ B * float(slope), rcond=None)
    b = Q @ b_set + P @ B * float(e)
    a, *_ = np.linalg.lstsq(M, Q @ (B * float(e) - b), rcond=None)
    return Q @ a, b


class HInfLaw:
    """H-infinity control law for :class:`controller.multimodel.MultiModelController` (SISO).

    A controller is synthesized for each model the first time it becomes
    active; fixed models keep theirs, an adaptive model's controller is
    re-synthesized only when its numerator/denominator parameters moved by more
    than ``resynthesis_threshold`` (relative 2-norm) since its last synthesis.
    Every change of controller is bumpless: the new controller's state is
    warmed up by running it over the last ``warm_samples`` tracking errors
    (so its dynamics carry the recent history), and ``u_hold`` is set so that
    the move is continuous. With input limits, the controller state is frozen
    while its update would push a clipped move further past the limit
    (directional conditional integration: no wind-up and no lock-up).

    After :meth:`align` (a move held from outside, e.g. a restart from an old
    checkpoint) the error history is unknown: a new controller's state then starts
    in equilibrium with the error (:func:`equilibrium_state`) instead of at zero,
    so that its fast modes do not kick the moves after the bumpless first one.

    Parameters
    ----------
    weights : HInfWeights
    dt : float
        Sample time.
    resynthesis_threshold : float
        Relative parameter change that triggers a new synthesis (> 0).
    u_min, u_max : float
        Input limits used for anti-windup (the controller also clips).
    warm_samples : int
        Error history used to initialize a new controller's state (0 = zero state).
    """

    def __init__(self, weights: HInfWeights, dt: float, resynthesis_threshold: float = 0.05,
                 u_min: float = -math.inf, u_max: float = math.inf,
                 warm_samples: int = 100) -> None:
        if not (math.isfinite(resynthesis_threshold) and resynthesis_threshold > 0):
            raise ValueError(f"resynthesis_threshold: must be > 0, got {resynthesis_threshold!r}")
        self.weights = weights
        self.dt = float(dt)
        self.threshold = float(resynthesis_threshold)
        self.u_min, self.u_max = float(u_min), float(u_max)
        if warm_samples < 0:
            raise ValueError(f"warm_samples: must be >= 0, got {warm_samples}")
        self.warm_samples = int(warm_samples)
        # python-control loaded here, at the law's construction: the first design is made
        # inside a sample, which must not also pay for the import (~2 s)
        import control  # noqa: F401

        self._errors: list[float] = []
        self._settled_start = False  # after align: new states start in equilibrium
        self._ramp_from: float | None = None  # after align: the first error, for the slope
        self._designs: dict[int, tuple[np.ndarray, DiscreteController]] = {}
        self.model: int | None = None
        self.ctrl: DiscreteController | None = None
        self.xk = np.zeros(0)
        self.u_hold = 0.0
        self.n_syntheses = 0
        self.n_synthesis_failures = 0
        self.n_controller_changes = 0
        self.n_saturated = 0
        self.last_gamma = math.nan

    def counters(self) -> dict[str, int]:
        return {"syntheses": self.n_syntheses, "synthesis_failures": self.n_synthesis_failures,
                "controller_changes": self.n_controller_changes,
                "saturated_samples": self.n_saturated}

    def reset(self, u, y) -> None:
        self.u_hold = float(np.asarray(u, dtype=float).reshape(-1)[0])
        self.model, self.ctrl, self.xk = None, None, np.zeros(0)
        self._errors = []
        self._settled_start = False
        self._ramp_from = None

    def align(self, u, y) -> None:
        """Bumpless take-over of the held move ``u`` at the measurement ``y``.

        As :meth:`reset` (the next move is ``u``: ``u_hold`` absorbs the controller's
        output), but the controller state is back-calculated in equilibrium with the
        current error rather than zero (until a full error history is collected).
        At the second sample, when the error's slope is known, the state is set once
        more on the trajectory of that error ramp (:func:`equilibrium_state`) and the
        move continues from the first one by the ramp's own increment, so the moves
        after the first one do not kick either.
        """
        self.reset(u, y)
        self._settled_start = True
        self._ramp_from = math.nan  # the first error, set at the first sample

    def applied(self, u, computed) -> None:
        """The plant got ``u`` instead of ``computed`` (the last move): the output offset
        absorbs the difference, so the next move is ``u`` plus the law's own increment."""
        self.u_hold += float(np.asarray(u, dtype=float).reshape(-1)[0]
                             - np.asarray(computed, dtype=float).reshape(-1)[0])

    @staticmethod
    def _model_params(ssm, j: int) -> np.ndarray:
        n = ssm.n_deg
        th = ssm.coefficient_theta(j)[:, 0]
        return np.concatenate((th[:n], th[n : 2 * n]))

    def _design_for(self, ssm, j: int, alarms: list[str]) -> DiscreteController | None:
        p = self._model_params(ssm, j)
        cached = self._designs.get(j)
        if cached is not None:
            p_d, ctrl = cached
            change = np.linalg.norm(p - p_d) / max(np.linalg.norm(p_d), 1e-12)
            if change <= self.threshold:
                return ctrl
        n = ssm.n_deg
        num, den = siso_model_tf(p[:n], p[n:], ssm.a)
        try:
            design = synthesize(num, den, self.weights, self.dt)
        except (HInfSynthesisError, ValueError) as exc:
            self.n_synthesis_failures += 1
            alarms.append(f"H-infinity synthesis for model {j} failed, previous controller "
                          f"kept: {exc}")
            # do not retry until the parameters move again
            if cached is None:
                return None
            self._designs[j] = (p, cached[1])
            return cached[1]
        self.n_syntheses += 1
        self.last_gamma = design.gamma
        self._designs[j] = (p, design.discrete)
        return design.discrete

    def compute(self, k, model, ssm, y, reference, u_last):
        if ssm.m != 1:
            raise ValueError("HInfLaw: SISO models only")
        alarms: list[str] = []
        ctrl = self._design_for(ssm, model, alarms)
        e = float(reference[0, 0] - y[0])
        u_prev = float(u_last[0])
        if ctrl is None and self.ctrl is None:
            return np.array([u_prev]), {"status": "no_controller", "fallback": True,
                                        "alarms": alarms}
        if ctrl is not None and ctrl is not self.ctrl:
            # bumpless change: warm state from the error history, the hold absorbs the rest
            self.ctrl = ctrl
            self.model = model
            if self._settled_start:  # no full history: start on the ramp of the first two
                hist = [*self._errors, e]
                x = equilibrium_state(ctrl, hist[0], hist[1] - hist[0] if len(hist) > 1
                                      else 0.0)[0]
            else:
                x = np.zeros(ctrl.nk)
            for e_old in self._errors:
                x = ctrl.A @ x + ctrl.B[:, 0] * e_old
            self.xk = x
            self.u_hold = u_prev - float(ctrl.C[0] @ x + ctrl.D[0, 0] * e)
            self.n_controller_changes += 1
        if self._ramp_from is not None:
            if math.isnan(self._ramp_from):
                self._ramp_from = e
            else:  # second sample after align: on the ramp, continue by its increment
                c = self.ctrl
                a, b = equilibrium_state(c, e, e - self._ramp_from)
                # x_0 - x_(-1) = b - c with c = P B slope (see equilibrium_state)
                c_ramp = _integrator_projector(c.A) @ c.B[:, 0] * (e - self._ramp_from)
                step = float(c.C[0] @ (b - c_ramp) + c.D[0, 0] * (e - self._ramp_from))
                self.xk = a
                self.u_hold = u_prev + step - float(c.C[0] @ a + c.D[0, 0] * e)
                self._ramp_from = None
        if self.warm_samples:
            self._errors.append(e)
            if len(self._errors) > self.warm_samples:
                del self._errors[0]
            if len(self._errors) >= self.warm_samples:
                self._settled_start = False  # a full history: warm up as usual
        c = self.ctrl
        u_raw = self.u_hold + float(c.C[0] @ self.xk + c.D[0, 0] * e)
        u = min(max(u_raw, self.u_min), self.u_max)
        x_new = c.A @ self.xk + c.B[:, 0] * e
        if u != u_raw:
            self.n_saturated += 1
            # directional conditional integration: freeze the state only while its
            # update would push the move further past the limit (no wind-up, no lock-up)
            push = float(c.C[0] @ (x_new - self.xk))
            if (u_raw > self.u_max and push > 0) or (u_raw < self.u_min and push < 0):
                x_new = self.xk
        self.xk = x_new
        return np.array([u]), {"status": "solved", "alarms": alarms}

    def checkpoint(self) -> dict[str, Any]:
        return {
            "designs": {str(j): {"p": p.tolist(), "ctrl": c.as_dict()}
                        for j, (p, c) in self._designs.items()},
            "model": self.model,
            "xk": self.xk.tolist(),
            "u_hold": self.u_hold,
            "errors": list(self._errors),
            "settled_start": self._settled_start,
            "ramp_from": self._ramp_from,
            "counters": [self.n_syntheses, self.n_synthesis_failures, self.n_controller_changes],
        }

    def restore(self, state: dict[str, Any]) -> None:
        self._designs = {int(j): (np.asarray(d["p"], dtype=float),
                                  DiscreteController.from_dict(d["ctrl"]))
                         for j, d in state["designs"].items()}
        self.model = state["model"]
        self.ctrl = None if self.model is None else self._designs[int(self.model)][1]
        self.xk = np.asarray(state["xk"], dtype=float)
        self.u_hold = float(state["u_hold"])
        self._errors = [float(v) for v in state.get("errors", [])]
        self._settled_start = bool(state.get("settled_start", False))
        ramp = state.get("ramp_from")
        self._ramp_from = None if ramp is None else float(ramp)
        self.n_syntheses, self.n_synthesis_failures, self.n_controller_changes = (
            int(v) for v in state["counters"])
