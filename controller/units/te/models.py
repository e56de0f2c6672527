"""TE linear models for the MPC of the §7.4 cascade as this project runs it.

Why not :mod:`controller.units.te.linear_models`: that module closes Table 7.10's loops as
printed (reactor-temperature gain -0.5 %/degC), which leaves the linearized plant
unstable at modes 0 and 2, and holds the E feed constant. The cascade that runs
the original plant here (:mod:`controller.units.te.control`) holds the reactor
temperature with integral action and ratios the E feed to the measured D feed (§7.7).
The MPC's model must be the plant it acts on, so this module linearizes that, with the
chapter-3 tooling, with one stand-in: the plant side cascades the reactor temperature
over the coolant outlet temperature (:data:`controller.units.te.loops.INNER_LOOPS`),
the models close a single temperature loop on the cooling water (-2 %/degC, Ti 0.5 h;
:data:`controller.units.te.loops.MODEL_LOOPS`). Both hold the temperature at T_r* at a
steady state, so the steady-state gains are the same; the models' temperature is
slower than the cascade's, and they keep no fast cascade modes:

1. Jacobian linearization of ``get_plant("te")`` (50 states, h) at the grade's
   tabulated state (Ricker 1995 / the base case);
2. the four inner PI loops closed (:data:`controller.units.te.loops.MODEL_LOOPS`,
   integrators as states), and the E/D ratio: XMV(2) deviation = r x XMV(1) valve
   deviation with r the grade's ratio in % of each valve range;
3. a unity-gain first-order filter on reactor pressure, 1/300 h (R7.10);
4. inputs XMV3, XMV4, P_r* (set point of the pressure loop on XMV6), T_r*, XMV11;
   outputs reactor pressure (filtered),
   separator temperature, separator pressure, stripper pressure, stripper
   temperature (R7.15);
5. balanced truncation with the DC gain matched (singular perturbation) to
   n = :data:`MPC_ORDER` = 10 for the MPC, in the orthonormal basis; n = :data:`ORDER`
   = 8 in the companion basis (as ch3_te: above that the companion coefficients lose
   accuracy); and the state-shared model with the three fixed models (modes 0, 2, 3)
   and, for strategy (b), one re-initialized adaptive model.

The order
---------
The state-shared models are strictly proper (``y(k)`` from the shared state alone),
so a reduced model keeps ``(A, B, C)`` and loses the feedthrough ``D`` that the
singular perturbation leaves for the discarded fast states. That ``D`` is the
models' DC error. With the reactor pressure loop closed (integral action on the
purge) the plant's steady gain to the reactor pressure is 1 from P_r* and 0 from
every other handle; at n = 8 the mode-0 model's gain from the condenser (XMV 11) to
the reactor pressure was +1.94 kPa/% and its gain to the separator temperature
+0.23 °C/% where the plant's is -0.69 (the sign that once pinned the condenser
in the MPC). Measured on the three grades (``closed_loop`` against
``reduced(g, n)``'s ``(A, B, C)``; ``python docs/te_model_order.py``):

===  ==================================  =======================================
 n   DC error (max |D|), modes 0/2/3     step-response error, modes 0 / 2 / 3
===  ==================================  =======================================
 8   1.94 / 0.96 / 0.99                  10.5 / 5.5 / 4.0  (of 9.5 / 17.9 / 9.1)
 10  0.44 / 0.60 / 0.42                  1.9 / 7.8 / 3.3
 12  0.22 / 0.15 / 0.13                  2.2 / 1.9 / 1.6
 16  0.06 / 0.09 / 0.04                  0.3 / 0.3 / 0.3
===  ==================================  =======================================

Step-response error: the largest deviation over 0.05-100 h from the full cascade's
response to steps of 10 % (XMV 3, 4, 11), 50 kPa (P_r*) and 1 °C (T_r*), in units of
the CV scales (20 kPa, 1 °C, 20 kPa, 20 kPa, 1 °C), against the largest response in
brackets. At n = 10 every DC gain to the reactor pressure is the plant's within 0.55
kPa per handle unit (0.15 at n = 12, 1.94 at n = 8), with the sign right where it
matters to the MPC: the condenser's gain to the pressure is 0.08 / -0.11 / 0.00 (n = 8:
+1.94 / +0.79 / -0.02) and to the separator temperature -0.82 / -1.83 / -0.00 °C/%
(the plant's -0.69 / -1.23 / -0.01). The adaptive model has 260 parameters instead
of 208 and the shared order is 100 instead of 80. Why not 12: at n = 12 mode 3's model
keeps a 45 h mode (pole -0.022 1/h) that omega, at mode 0's poles, does not hold; its
estimates amplify the measurement noise (errors of ~240 CV scales at mode 3) and the
switching index no longer picks it there, and with omega at mode 3's poles the mode-2
model drove the condenser from 13 to 85 % in a quarter of an hour in 1 -> 2 and the
plant tripped (see :class:`controller.units.te.control.TEMPCOptions` ``basis_grade``).
In the closed loop the MPC holds its pressure limit only with models whose DC gains
are right (``TEMPCOptions.pressure_soft_max``).

The order-10 models leave out the cascade's slowest modes (-0.14 1/h at mode 2, -0.023
at mode 3; the models' slowest are -0.28 to -0.32), and the switching index depends on
it. With a tighter reactor-temperature loop (-2.5 %/degC or more) the truncation keeps
them, and omega, at mode 0's poles, does not hold them: with -6 %/degC the fixed
models' one-step errors at their own grade rose (mode 2's 0.30 -> 0.52, mode 3's 2.6 ->
6.3 CV scales, medians over 12 h)
and in strategy ``fixed`` the index left mode 0's model 8.8 h after the 0 -> 2 request
(2.6 h with -2 %/degC) and 14.9 h after 0 -> 3 (1.6 h), while it reached mode 0's 4.1
h into 3 -> 0 (not within 16 h with -2) (seed 1; ``docs/te_matrix.md``, "The reactor
temperature's inner loop").
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from controller.linear import Realization, balanced_truncation
from controller.shared_basis import BASES, SharedBasis, roots_from_poles
from controller.state_shared import ModelSpec, StateSharedModel, designer_polynomial

__all__ = ["MODEL_GRADES", "ADAPTIVE_MODEL", "ORDER", "MPC_ORDER", "DESIGNER_ROOTS",
           "CascadeStateSpace", "cascade_state_space", "closed_loop", "reduced",
           "state_shared_model", "PRESSURE_FILTER_H"]

MODEL_GRADES = ("mode0", "mode2", "mode3")
#: The name of strategy (b)'s re-initialized adaptive model (seed §4, eq. 4.1) beside
#: the fixed models of :data:`MODEL_GRADES`, as the index and the status report it.
ADAPTIVE_MODEL = "reinit"
#: The companion basis's order (the seed's coordinates, :data:`DESIGNER_ROOTS`).
ORDER = 8
#: The MPC's order (orthonormal basis; see "The order" above).
MPC_ORDER = 10
PRESSURE_FILTER_H = 1.0 / 300.0
#: roots of the designer polynomial, 1/h: a geometric spread over the retained poles
DESIGNER_ROOTS = tuple(-np.geomspace(0.05, 20.0, ORDER))
#: inputs: ("xmv", number) or ("sp", index of the inner loop whose set point it is)
_CORE_INPUTS = (("xmv", 3), ("xmv", 4), ("sp", 4), ("sp", 0), ("xmv", 11))
_CORE_CVS = (7, 11, 13, 16, 18)


@dataclass(frozen=True)
class CascadeStateSpace:
    """The linearized plant with the inner loops and the E/D ratio closed (time in h).

    ``A`` (N, N) holds the plant's 50 states first, then one integrator per loop, one
    per secondary of a cascaded loop and the pressure filter; ``B_sp`` (N, loops) takes
    the loops' set points; ``B_xmv`` (N, 12) and ``C_xmeas`` (41, N) are the plant's own
    input and output matrices padded to the N states; ``lm`` the plant's linearization.
    """

    A: np.ndarray
    B_sp: np.ndarray
    B_xmv: np.ndarray
    C_xmeas: np.ndarray
    lm: object
    ratio: float


@lru_cache(maxsize=8)
def cascade_state_space(grade: str, loops: tuple | None = None) -> CascadeStateSpace:
    """The cascade about ``grade`` as :class:`CascadeStateSpace` (see
    :func:`closed_loop`, which takes its core inputs and outputs from it)."""
    from controller.units.te.grades import grade as get_grade
    from controller.units.te.loops import MODEL_LOOPS
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    lps = MODEL_LOOPS if loops is None else tuple(loops)

    g = get_grade(grade)
    plant = get_plant("te")
    lm = linearize(plant, plant.operating_point(g.name))
    A, B, C = lm.A.copy(), lm.B, lm.C
    nx, nl = A.shape[0], len(lps)
    # E/D ratio: XMV2 follows the D valve position (state 39) in % of its range
    ratio = g.xmv[1] / g.xmv[0]
    A[:, 38] += B[:, 1] * ratio
    # states: the plant's, one integrator per loop, one per secondary of a cascaded loop
    # (after the loops' own), the pressure filter
    sec = [k for k, lp in enumerate(lps) if lp.secondary is not None]
    N = nx + nl + len(sec) + 1
    plain = [k for k in range(nl) if k not in sec]
    Kc = np.array([lps[k].gain for k in plain])
    Ti = np.array([lps[k].ti_h for k in plain])
    CL = C[[lps[k].cv - 1 for k in plain]]
    BL = B[:, [lps[k].mv - 1 for k in plain]]
    z = [nx + k for k in plain]
    Acl = np.zeros((N, N))
    Bsp = np.zeros((N, nl))  # the loops' set points as inputs
    # plain loops: u = Kc (r - y) + Kc/Ti z, z' = r - y
    Acl[:nx, :nx] = A - BL @ np.diag(Kc) @ CL
    Acl[:nx, z] = BL @ np.diag(Kc / Ti)
    Acl[z, :nx] = -CL
    Bsp[:nx, plain] = BL * Kc
    Bsp[z, plain] = 1.0  # paired indices: loop k's integrator takes its set point
    for k in sec:
        lp = lps[k]
        b, c, zk = B[:, lp.mv - 1], C[lp.cv - 1], nx + k
        # cascade: r_s = Kp (r - y) + Kp/Tp z; u = Ks (r_s - y_s) + Ks/Ts z_s, z_s' = r_s - y_s
        s2, cs, zs = lp.secondary, C[lp.secondary.cv - 1], nx + nl + sec.index(k)
        rs_x, rs_z = -lp.gain * c, lp.gain / lp.ti_h  # r_s's dependence on x and z
        Acl[:nx, :nx] += s2.gain * np.outer(b, rs_x - cs)
        Acl[:nx, zk] += b * s2.gain * rs_z
        Acl[:nx, zs] += b * s2.gain / s2.ti_h
        Acl[zk, :nx] = -c
        Acl[zs, :nx] = rs_x - cs
        Acl[zs, zk] = rs_z
        Bsp[:nx, k] = b * s2.gain * lp.gain
        Bsp[zk, k] = 1.0
        Bsp[zs, k] = lp.gain
    Acl[-1, :nx] = C[_CORE_CVS[0] - 1] / PRESSURE_FILTER_H
    Acl[-1, -1] = -1.0 / PRESSURE_FILTER_H
    B_xmv = np.zeros((N, B.shape[1]))
    B_xmv[:nx] = B
    C_xmeas = np.zeros((C.shape[0], N))
    C_xmeas[:, :nx] = C
    return CascadeStateSpace(Acl, Bsp, B_xmv, C_xmeas, lm, float(ratio))


@lru_cache(maxsize=8)
def closed_loop(grade: str, loops: tuple | None = None
                ) -> tuple[Realization, np.ndarray, np.ndarray]:
    """Linear cascade about ``grade``: (realization, u_op (5,), y_op (5,)), time in h.

    ``loops``: the inner loops closed (default :data:`controller.units.te.loops.MODEL_LOOPS`),
    in their order; the first holds the reactor temperature (its set point is T_r*) and
    may be a cascade (a :class:`plant_sim.tennessee_eastman.regulatory.SecondaryLoop`
    on a faster measurement drives its valve); the fifth is the pressure loop.
    """
    from controller.units.te.loops import MODEL_LOOPS

    lps = MODEL_LOOPS if loops is None else tuple(loops)
    cs = cascade_state_space(grade, loops)
    lm, N = cs.lm, cs.A.shape[0]
    Bcl = np.zeros((N, 5))
    for j, (kind, idx) in enumerate(_CORE_INPUTS):
        Bcl[:, j] = cs.B_sp[:, idx] if kind == "sp" else cs.B_xmv[:, idx - 1]
    Ccl = np.zeros((5, N))
    Ccl[0, -1] = 1.0
    for i, cv in enumerate(_CORE_CVS[1:], start=1):
        Ccl[i] = cs.C_xmeas[cv - 1]
    Acl = cs.A
    y = lm.y_op
    u_op = np.array([lm.u_op[idx - 1] if kind == "xmv" else y[lps[idx].cv - 1]
                     for kind, idx in _CORE_INPUTS])
    y_op = np.array([y[cv - 1] for cv in _CORE_CVS])
    return Realization(Acl, Bcl, Ccl, None), u_op, y_op


@lru_cache(maxsize=8)
def reduced(grade: str, order: int = ORDER):
    """Balanced truncation of :func:`closed_loop` (DC gain matched, with the fast
    states' steady contribution in the feedthrough ``D``, which the state-shared
    models drop: see "The order" above)."""
    sys, _, _ = closed_loop(grade)
    return balanced_truncation(sys, order=order, method="matchdc", unstable="keep")


def state_shared_model(dt_h: float, adaptive: bool, order: int = ORDER,
                       roots=None, basis: str = "companion",
                       roots_grade: str = "mode0") -> StateSharedModel:
    """State-shared model: fixed modes 0, 2, 3 (+ one adaptive slot "reinit" at mode 0,
    placed first).

    Parameters
    ----------
    dt_h : float
        Sample time, h.
    adaptive : bool
        Add the adaptive slot (strategy b).
    order : int
        n, the reduced order of every mode.
    roots : sequence of complex, optional
        omega's roots, 1/h. Default: :data:`DESIGNER_ROOTS` (companion basis); the
        poles of ``roots_grade``'s model (orthonormal basis,
        :func:`controller.shared_basis.roots_from_poles`).
    roots_grade : str
        The grade of :data:`MODEL_GRADES` whose model's poles omega holds (orthonormal
        basis, ``roots`` not given). See :class:`controller.units.te.control.TEMPCOptions`
        ``basis_grade`` for the measured choice (mode 0's at the MPC's order 10).
    basis : {"companion", "orthonormal"}
        Coordinates of the shared state (:mod:`controller.shared_basis`).
    """
    if basis not in BASES:
        raise ValueError(f"basis: must be one of {BASES}, got {basis!r}")
    if basis == "companion":
        a = designer_polynomial(DESIGNER_ROOTS if roots is None else roots)
        n_roots = a.size
    else:
        if roots is None:
            if roots_grade not in MODEL_GRADES:
                raise ValueError(f"roots_grade: must be one of {MODEL_GRADES}, got "
                                 f"{roots_grade!r}")
            roots = roots_from_poles(reduced(roots_grade, order).reduced.poles())
        a = SharedBasis.orthonormal(roots)
        n_roots = a.n
    if n_roots != order:
        raise ValueError(f"roots: expected {order} roots (the order), got {n_roots}")
    specs = []
    for g in MODEL_GRADES:
        _, u_op, y_op = closed_loop(g)
        r = reduced(g, order).reduced
        specs.append(StateSharedModel.model_from_linear(g, r.A, r.B, r.C, u_op, y_op, a))
    ssm = StateSharedModel(a, 5, dt_h)
    if adaptive:
        # First slot: on a tie of the index (right after a re-initialization the
        # adaptive model and its source have the same J) the smallest-J rule picks
        # the lowest index, which must be the adaptive model or it would be
        # re-initialized again at every sample and never adapt.
        ssm.add_model(ModelSpec(ADAPTIVE_MODEL, specs[0].theta, specs[0].bias, "adaptive"))
    for spec in specs:
        ssm.add_model(spec)
    return ssm
