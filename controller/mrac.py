"""Model reference adaptive control on the selected model (seed §5.1).

Plant (deviation variables) ``kp (s + z) / (s^2 + a1 s + a0)`` (n = 2, relative
degree 1), reference model (eq. 5.10)

    Wm(s) = (s + 1) / (s^2 + 2 s + 1) = km Zm / Rm,   km = 1, Zm = s + 1, Rm = (s + 1)^2

and the model-reference control law (Ioannou & Sun, §6.3; seed eq. 5.4-5.6)

    u = theta1 w1 + theta2 w2 + theta3 y + c0 r,    w1 = u / Lambda,  w2 = y / Lambda

with the filter ``Lambda(s) = Lambda0 Zm = s + 1``. Perfect matching
(closed loop ``y = Wm r``) holds when

    theta1 Rp + kp (theta2 + theta3 Lambda) Zp = Lambda Rp - Zp Lambda0 Rm,   c0 = km / kp

which for n = 2 is three linear equations in (theta1, theta2, theta3). The
seed's parametric model (Table 5.4) stores ``p* = [kp, -kp theta1, -kp theta3,
-kp theta2]``; :func:`table_5_4_row` returns that vector.

The multiple-model law is *indirect*: the selected model's transfer function
(from the state-shared parameters) gives kp, z, a1, a0, and the matching
equation gives the controller. Models whose zero is not in the left half plane
(matching would cancel an unstable zero) or whose gain is ~0 are rejected and
the previous controller is kept (counted).

Operating point: the law runs in absolute units with a constant
``u_bar = (1 - theta1) u0(model)`` where ``u0`` is the model's steady input at
``y = 0`` (from its bias), so that the model's steady state is an equilibrium of
the loop; the filters are stepped exactly (ZOH) once per sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.hinf import siso_model_tf

__all__ = ["MRACGains", "matching_gains", "table_5_4_row", "MRACLaw", "reference_model_step"]


@dataclass(frozen=True)
class MRACGains:
    """Controller parameters of the model-reference law (see module notes)."""

    theta1: float
    theta2: float
    theta3: float
    c0: float

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.theta1, self.theta2, self.theta3, self.c0)


def matching_gains(kp: float, z: float, a1: float, a0: float, km: float = 1.0) -> MRACGains:
    """Solve the matching equation for ``kp (s + z)/(s^2 + a1 s + a0)`` and Wm = km/(s+1).

    Raises
    ------
    ValueError
        If ``kp`` is zero/non-finite or the plant zero ``-z`` is not in the open
        left half plane (the law cancels it).
    """
    vals = (kp, z, a1, a0, km)
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("kp, z, a1, a0, km: must be finite")
    if abs(kp) < 1e-9:
        raise ValueError(f"kp: high-frequency gain must be nonzero, got {kp}")
    if not z > 0:
        raise ValueError(f"z: plant zero -z must be stable (z > 0), got z = {z}")
    # coefficients of s^2, s, 1 (Lambda = s + 1, Rm = (s + 1)^2, Lambda0 = 1)
    A = np.array([[1.0, 0.0, kp], [a1, kp, kp * (1.0 + z)], [a0, kp * z, kp * z]])
    b = np.array([a1 - 1.0 - z, a1 + a0 - 1.0 - 2.0 * z, a0 - z])
    t1, t2, t3 = np.linalg.solve(A, b)
    return MRACGains(float(t1), float(t2), float(t3), km / kp)


def table_5_4_row(kp: float, z: float, a1: float, a0: float) -> tuple[float, float, float, float]:
    """Seed Table 5.4 entry ``(k1, k2, k3, k4) = (kp, -kp theta1, -kp theta3, -kp theta2)``."""
    g = matching_gains(kp, z, a1, a0)
    return (kp, -kp * g.theta1, -kp * g.theta3, -kp * g.theta2)


def reference_model_step(ym: float, r: float, dt: float) -> float:
    """Advance ``ym`` of ``Wm = 1/(s + 1)`` one sample with r held (exact)."""
    a = math.exp(-dt)
    return a * ym + (1.0 - a) * r


class MRACLaw:
    """Model-reference control law for :class:`controller.multimodel.MultiModelController`.

    Parameters
    ----------
    dt : float
        Sample time.
    u_min, u_max : float
        Input limits (the filter ``w1`` sees the applied, clipped input).
    """

    def __init__(self, dt: float, u_min: float = -math.inf, u_max: float = math.inf) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.dt = float(dt)
        self.u_min, self.u_max = float(u_min), float(u_max)
        self.decay = math.exp(-self.dt)
        self.w1 = 0.0
        self.w2 = 0.0
        self.gains: MRACGains | None = None
        self.u_bar = 0.0
        self.model: int | None = None
        self.n_rejected = 0
        self.n_gain_changes = 0
        self.last_plant: tuple[float, float, float, float] | None = None
        self._align_u: float | None = None  # a held move to take over at the next sample

    def counters(self) -> dict[str, int]:
        return {"mrac_rejected_models": self.n_rejected, "mrac_gain_changes": self.n_gain_changes}

    def reset(self, u, y) -> None:
        u0 = float(np.asarray(u, dtype=float).reshape(-1)[0])
        y0 = float(np.asarray(y, dtype=float).reshape(-1)[0])
        self.w1, self.w2 = u0, y0  # filters at steady state (Lambda(0) = 1)
        self.gains, self.model = None, None
        self._align_u = None

    def align(self, u, y) -> None:
        """Bumpless take-over of the held move ``u`` at the measurement ``y``.

        As :meth:`reset`, then at the first sample the input filter's state ``w1`` is
        back-calculated so that the control law gives exactly ``u`` for the current
        ``y`` and reference (with ``w2 = y``, the output filter at steady state); the
        loop continues from there through the filter dynamics. Left at ``w1 = u`` when
        the gain ``theta1`` on ``w1`` is zero.
        """
        self.reset(u, y)
        self._align_u = float(np.asarray(u, dtype=float).reshape(-1)[0])

    def applied(self, u, computed) -> None:
        """The plant got ``u`` instead of ``computed``: the input filter ``w1`` (advanced
        with ``computed`` in :meth:`compute`) is corrected to have seen ``u``."""
        du = float(np.asarray(u, dtype=float).reshape(-1)[0]
                   - np.asarray(computed, dtype=float).reshape(-1)[0])
        self.w1 += (1.0 - self.decay) * du

    @staticmethod
    def plant_of(ssm, j: int) -> tuple[tuple[float, float, float, float], float]:
        """``(kp, z, a1, a0)`` of SISO model j and its steady input at y = 0."""
        n = ssm.n_deg
        if n != 2 or ssm.m != 1:
            raise ValueError("MRACLaw: needs a SISO state-shared model with n = 2")
        th = ssm.coefficient_theta(j)[:, 0]
        num, den = siso_model_tf(th[:n], th[n:], ssm.a)
        kp = float(num[0])
        z = float(num[1] / num[0]) if kp != 0 else math.nan
        a1, a0 = float(den[1]), float(den[2])
        # steady state of y = th1' n1 + th2' n2 + b with n = [v/a_1, 0]: u(y) = ...
        a_1 = float(ssm.a[0])
        b = float(ssm.bias(j)[0])
        u_at_y0 = -b * a_1 / th[0] if th[0] != 0 else math.nan
        return (kp, z, a1, a0), u_at_y0

    def compute(self, k, model, ssm, y, reference, u_last):
        alarms: list[str] = []
        yv = float(y[0])
        r = float(reference[0, 0])
        if model != self.model or ssm.kinds[model] != "fixed" or self.gains is None:
            try:
                plant, u0 = self.plant_of(ssm, model)
                gains = matching_gains(*plant)
                if not math.isfinite(u0):
                    raise ValueError("model has no steady input (zero DC gain)")
                if gains != self.gains:
                    self.n_gain_changes += 1
                self.gains, self.model, self.last_plant = gains, model, plant
                self.u_bar = (1.0 - gains.theta1) * u0
            except (ValueError, np.linalg.LinAlgError) as exc:
                self.n_rejected += 1
                if self.gains is None:
                    return np.array([float(u_last[0])]), {
                        "status": "no_controller", "fallback": True,
                        "alarms": [f"MRAC: model {model} rejected: {exc}"]}
                alarms.append(f"MRAC: model {model} rejected, previous gains kept: {exc}")
                self.model = model
        g = self.gains
        if self._align_u is not None:
            rest = g.theta2 * self.w2 + g.theta3 * yv + g.c0 * r + self.u_bar
            if g.theta1 != 0.0 and math.isfinite(g.theta1):
                self.w1 = (self._align_u - rest) / g.theta1
            self._align_u = None
        u = g.theta1 * self.w1 + g.theta2 * self.w2 + g.theta3 * yv + g.c0 * r + self.u_bar
        u = min(max(u, self.u_min), self.u_max)
        # filters 1/(s+1) with u and y held over the sample
        self.w1 = self.decay * self.w1 + (1.0 - self.decay) * u
        self.w2 = self.decay * self.w2 + (1.0 - self.decay) * yv
        return np.array([u]), {"status": "solved", "alarms": alarms}

    def checkpoint(self) -> dict[str, Any]:
        return {"w1": self.w1, "w2": self.w2, "u_bar": self.u_bar, "model": self.model,
                "gains": None if self.gains is None else list(self.gains.as_tuple()),
                "counters": [self.n_rejected, self.n_gain_changes], "align_u": self._align_u}

    def restore(self, state: dict[str, Any]) -> None:
        self.w1, self.w2 = float(state["w1"]), float(state["w2"])
        self.u_bar = float(state["u_bar"])
        self.model = state["model"]
        self.gains = None if state["gains"] is None else MRACGains(*state["gains"])
        self.n_rejected, self.n_gain_changes = (int(v) for v in state["counters"])
        align_u = state.get("align_u")
        self._align_u = None if align_u is None else float(align_u)
