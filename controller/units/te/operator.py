"""The operator's per-variable settings on the TE supervisory controller (seed §7.4/7.7
cascade, :mod:`controller.units.te.control`), applied before each step.

What each kind of variable offers (:meth:`TEOperatorLayer.capabilities`):

- the MPC's five handles (XMV 3, XMV 4, P_r*, T_r*, XMV 11; MPC strategies):
  ``manual`` and ``off`` hold the handle at its value and the MPC plans the other
  handles around it (:class:`~controller.units.mpc_operator.MPCOperatorLayer`: its
  moves are fixed at zero in the QP, its last move is the held value); operator limits
  are the QP's hard input limits of the sample;
- the other MVs (E/D ratio XMV 2, plan-driven XMV 5, 9, 12, the level set points):
  held or limited on the move itself (:class:`controller.units.operator.OperatedController`);
  a held XMV 2 keeps the ratio loop tracking the valve, so ``auto`` resumes from it;
- the MPC's five CVs (XMEAS 7, 11, 13, 16, 18): ``off`` removes the CV from the
  objective (its weight Ξ is 0) and from the soft limits (the QP is rebuilt when the
  set of CVs switched off changes: ~3 ms for the four models, measured on this 2-core
  machine). The reactor pressure XMEAS 7 takes operator limits as limits of the
  steady-state targets (:mod:`controller.units.te.targets`, rank 1): the MPC is steered
  to a steady state within them (the pressure set point's target moves), never given
  them as dynamic constraints. The other four take none (:data:`SOFT_LIMITS_UNSAFE`):
  as the MPC's soft output limits they trip the plant when one binds, and the targets
  cannot meet them (only P_r*'s target moves, see
  :class:`~controller.units.te.targets.CoreTargetSettings`);
- the outer loops' CVs (XMEAS 17 production, 23 A in feed, 40 G in product): ``off``
  holds that loop's integral (:meth:`~controller.units.te.control.TEController.
  hold_outer_loops`); no operator limits (no constraint acts on them); XMEAS 11 off
  also holds the separator-temperature trim of the condenser's target;
- every other XMEAS is measured only (a 422 says so).

In warm mode every outer loop holds its integral (its output is not written, so it
must not wind up) and the ratio loop tracks the applied E feed valve.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from controller.operator_modes import CV_MODES, MV_MODES
from controller.units.mpc_operator import MPCOperatorLayer

__all__ = ["TEOperatorLayer", "CORE_CV_NAMES"]

#: Why the MPC's CVs take no operator limits (measured with noise on, from mode 0): the
#: TE MPC's soft output limits below a CV's value drive the condenser cooling XMV 11 to
#: 0 and the plant trips on reactor pressure: its own soft pressure limit at 2695 kPa
#: (``TEMPCOptions(pressure_soft_max=2695)``, no operator code involved) at 0.59 h, an
#: operator high limit on XMEAS 11 at 79.5 degC at 0.69 h.
SOFT_LIMITS_UNSAFE = ("the TE MPC's soft output limits below the value drive XMV 11 the "
                      "wrong way and trip the plant on reactor pressure; limit the loop's "
                      "set point instead (reactor_pressure_sp, reactor_temperature_sp)")
#: The MPC's CVs as unit CV names (:data:`controller.units.te.control.CORE_CVS`).
CORE_CV_NAMES = ("XMEAS7", "XMEAS11", "XMEAS13", "XMEAS16", "XMEAS18")
#: The core CVs whose operator limits the steady-state targets take (reactor pressure).
TARGET_LIMITED = ("XMEAS7",)
TARGET_LIMIT_NOTE = ("operator limits act on the steady-state targets (rank 1): the "
                     "pressure set point's target moves so the plant settles within them "
                     "(a slow layer: about 1 h time constant; the interlock and the high-"
                     "pressure override guard the fast excursions)")
#: Core CVs that also drive an outer trim (the separator temperature on the
#: condenser's target): switched off, that trim holds too.
TRIMMING_CORE_CVS = ("XMEAS11",)
_OUTER = {"XMEAS17": "production loop (XMEAS 17 -> A+C feed target)",
          "XMEAS23": "A-in-feed loop (XMEAS 23 -> A feed target)",
          "XMEAS40": "G-in-product loop (XMEAS 40 -> D share of the D+E feed)"}


class TEOperatorLayer:
    """Applies an :class:`~controller.units.operator.OperatorView` to one TE controller.

    Parameters
    ----------
    ctl : controller.units.te.control.TEController
    mvs : tuple of str
        The unit's MV names (move order).
    core_idx : list of int or None
        For each of the five handles its index in ``mvs`` (None: not an MV of the unit).
    """

    def __init__(self, ctl, mvs: tuple[str, ...], core_idx) -> None:
        from controller.units.te.structure import TE_XMEAS

        self.ctl = ctl
        self.mvs = tuple(mvs)
        self.core_idx = list(core_idx)
        core = getattr(ctl, "core", None)
        self.mpc = (MPCOperatorLayer(core, self.core_idx,
                                     [TE_XMEAS.index(n) for n in CORE_CV_NAMES])
                    if None not in self.core_idx and MPCOperatorLayer.fits(core) else None)
        self._last_view = None
        self._mpc_view = None  # the view as the MPC gets it (XMEAS 7's limits removed)

    @property
    def targets(self):
        """The controller's steady-state targets (None: strategy without them)."""
        return getattr(self.ctl, "targets", None) if self.has_mpc else None

    @property
    def has_mpc(self) -> bool:
        return self.mpc is not None

    def capabilities(self, cv_names, mv_names) -> dict[str, dict]:
        caps: dict[str, dict] = {}
        for n in mv_names:
            caps[n] = {"modes": MV_MODES, "limits": True, "controlled": True}
        for n in cv_names:
            if self.has_mpc and n in TARGET_LIMITED and self.targets is not None:
                caps[n] = {"modes": CV_MODES, "limits": True, "controlled": True,
                           "note": TARGET_LIMIT_NOTE}
            elif self.has_mpc and n in CORE_CV_NAMES:
                caps[n] = {"modes": CV_MODES, "limits": False, "controlled": True,
                           "note": SOFT_LIMITS_UNSAFE}
            elif self.has_mpc and n in _OUTER:
                caps[n] = {"modes": CV_MODES, "limits": False, "controlled": True,
                           "note": f"held by the {_OUTER[n]}, no constraint acts on it"}
            else:
                caps[n] = {"note": "measured only: no loop of this strategy's supervisory "
                                   "controller acts on it"}
        return caps

    def apply(self, view, cv_names) -> None:
        """Before the step: the view's held handles, limits and CVs off."""
        if view is not self._last_view:
            self._last_view = view
            cv_index = {n: i for i, n in enumerate(cv_names)}
            held = {int(n[5:]) for n in (*_OUTER, *TRIMMING_CORE_CVS)
                    if n in cv_index and not view.cv_on[cv_index[n]]}
            if view.mode == "warm":
                held = set(getattr(self.ctl, "OUTER_LOOP_CVS", ()))
            hold = getattr(self.ctl, "hold_outer_loops", None)
            if callable(hold):  # not in the decentralized baseline
                hold(held)
            self._mpc_view = self._route_target_limits(view, cv_index)
            lead = getattr(self.ctl, "hold_pressure_lead", None)
            pr = self.core_idx[2]
            if callable(lead) and pr is not None:  # P_r* held: written as the operator set it
                lead(bool(view.mv_held[pr]))
        if self.mpc is not None:
            self.mpc.apply(self._mpc_view)

    def _route_target_limits(self, view, cv_index):
        """The operator limits of :data:`TARGET_LIMITED` to the steady-state targets;
        the view the MPC gets, without them."""
        targets = self.targets
        if targets is None:
            return view
        lo, hi = np.full(5, -np.inf), np.full(5, np.inf)
        cv_lo, cv_hi = view.cv_lo.copy(), view.cv_hi.copy()
        for n in TARGET_LIMITED:
            i = cv_index.get(n)
            if i is None or not view.cv_on[i]:
                continue
            k = CORE_CV_NAMES.index(n)
            lo[k], hi[k] = view.cv_lo[i], view.cv_hi[i]
            cv_lo[i], cv_hi[i] = -np.inf, np.inf
        targets.set_operator_limits(lo, hi)
        return replace(view, cv_lo=cv_lo, cv_hi=cv_hi)
