"""The TE unit's structure as the service sees it: MV vector, loops, grades, checks.

The plant side runs the inner loops of the cascade (:data:`controller.units.te.control.
INNER_LOOPS`) at the 1.8 s Euler step; the controller writes the free valves and one
set point per loop (:func:`te_mv_names`); under ``"decentralized"`` the loops are
:data:`controller.units.te.decentralized.PLANT_LOOPS`, whose cascade loops write
some set points themselves (those are not MVs). The grades are seed Table 7.3's rows
(:mod:`controller.units.te.grades`) with the modes' steady valves.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["TE_EULER_STEP_S", "TE_STRATEGIES", "TE_XMEAS", "check_config", "grade_values",
           "te_mv_names", "te_setpoint_name", "te_structure"]

TE_EULER_STEP_S = 1.8

TE_STRATEGIES = ("ssmpc", "fixed", "pi", "decentralized", "plan")

TE_XMEAS = tuple(f"XMEAS{i}" for i in range(1, 42))



#: The TE modes as an engineer knows them (seed Table 7.1, after Downs & Vogel 1993 and
#: Ricker 1995): G/H mass ratio and product rates (stream 11) in kg/h, None for the
#: maximum-production modes. Mode 2: Table 7.1 prints 1048 kg/h G, transposed digits
#: (1408 / (1408 + 12669) = 10.0 %, the ratio the table gives).
TE_MODE_PRODUCTS = {
    "mode0": ("50/50", (7038.0, 7038.0)),
    "mode1": ("50/50", (7038.0, 7038.0)),
    "mode2": ("10/90", (1408.0, 12669.0)),
    "mode3": ("90/10", (10000.0, 1111.0)),
    "mode4": ("50/50", None),
    "mode5": ("10/90", None),
    "mode6": ("90/10", None),
}

def te_setpoint_name(loop) -> str:
    """MV name of a TE inner loop's set point: ``"reactor level"`` → ``reactor_level_sp``."""
    return loop.name.replace(" ", "_") + "_sp"


def te_structure(strategy: str = "pi") -> tuple[tuple, tuple[int, ...]]:
    """``(inner loops, XMVs the supervisory controller writes)`` of the TE cascade.

    From the TE controller's spec (:class:`controller.units.te.control.TEControlSpec`).
    The plant side runs these loops; the controller's MV vector is the written XMVs,
    then one set point per loop (:func:`te_mv_names`).
    """
    if strategy == "decentralized":
        from controller.units.te.decentralized import decentralized_spec

        spec = decentralized_spec(TE_EULER_STEP_S * 20 / 3600.0, 20)
    else:  # imported here: the cascade loads the plant's compiled kernels
        from controller.units.te.control import TEControlSpec

        spec = TEControlSpec(strategy, TE_EULER_STEP_S * 20 / 3600.0, 20)
    return tuple(spec.loops), tuple(spec.written_xmvs)


def _written_loops(loops) -> tuple:
    """The loops whose set point the supervisory controller writes: all but those a
    plant-side cascade loop writes (:class:`plant_sim.tennessee_eastman.regulatory.
    CascadeLoop`)."""
    inner = {getattr(lp, "inner", None) for lp in loops}
    return tuple(lp for lp in loops if lp.name not in inner)


def te_mv_names(cfg) -> tuple[str, ...]:
    """The TE unit's MV vector: explicit ``cfg.mvs``, else the cascade's (te_structure)."""
    if cfg.mvs:
        return tuple(cfg.mvs)
    loops, written = te_structure(cfg.strategy)
    return tuple(f"XMV{i}" for i in written) + tuple(te_setpoint_name(lp)
                                                     for lp in _written_loops(loops))


def check_config(cfg) -> None:
    if tuple(cfg.cvs) != TE_XMEAS:
        raise ValueError("cvs: the TE unit measures all 41 XMEAS (XMEAS1..XMEAS41, in order)")
    if cfg.mvs:
        loops, _ = te_structure(cfg.strategy)
        sps = {te_setpoint_name(lp) for lp in _written_loops(loops)}
        owned = {f"XMV{lp.mv}" for lp in loops if hasattr(lp, "mv")}
        allowed = {f"XMV{i}" for i in range(1, 13)} | sps
        for name in cfg.mvs:
            if name in owned:
                raise ValueError(f"mvs: {name} is driven by an inner loop; write its set "
                                 f"point instead ({', '.join(sorted(sps))})")
            if name not in allowed:
                raise ValueError(f"mvs: unknown TE MV {name!r}; use XMV1..XMV12 or "
                                 f"{', '.join(sorted(sps))}")
    if cfg.strategy not in TE_STRATEGIES:
        raise ValueError(f"strategy: expected one of {TE_STRATEGIES}, got {cfg.strategy!r}")
    from plant_sim.tennessee_eastman.modes import MODES, grade_name

    grades = [grade_name(m) for m in MODES]
    if cfg.initial_grade not in grades:
        raise ValueError(f"initial_grade: unknown TE grade {cfg.initial_grade!r}; known: "
                         f"{', '.join(grades)}")
    n = cfg.sample_period_s / TE_EULER_STEP_S
    if abs(n - round(n)) > 1e-9 or round(n) < 1:
        raise ValueError(f"sample_period_s: must be a multiple of the TE Euler step "
                         f"{TE_EULER_STEP_S} s, got {cfg.sample_period_s}")


def grade_values(cfg) -> dict[str, dict[str, Any]]:
    """TE grades: noise-free XMEAS at each mode's start state as CV set points; the
    mode's XMVs and its regulatory set points (the loops' CVs there) as MVs."""
    from controller.units.te.grades import BACKOFF_GRADES
    from controller.units.te.grades import grade as te_grade
    from plant_sim.tennessee_eastman.modes import MODES, grade_name

    cvi = [int(n[5:]) - 1 for n in cfg.cvs]
    mvs = te_mv_names(cfg)
    loops, _ = te_structure(cfg.strategy)
    sp_cv = {te_setpoint_name(lp): lp.cv for lp in loops}
    out = {}
    for mode in MODES:
        g = te_grade(grade_name(mode))
        # the grade table's measurements (seed Table 7.3 rows; modes 4-6 their back-off)
        # as the CV set points, its valves (the mode's start state; modes 4-6 the
        # back-off's) as the MVs
        y0 = np.asarray(g.xmeas, dtype=float)
        mv = []
        for name in mvs:
            if name in sp_cv:
                mv.append(float(y0[sp_cv[name] - 1]))
            else:
                mv.append(float(g.xmv[int(name[3:]) - 1]))
        ratio, rates = TE_MODE_PRODUCTS[grade_name(mode)]
        rate_text = ("maximum production rate" if rates is None else
                     f"{rates[0]:.0f} kg/h G + {rates[1]:.0f} kg/h H")
        if g.name in BACKOFF_GRADES:
            rate_text = (f"{rate_text}, backed off to {g.xmeas[16]:.2f} m3/h product so "
                         f"that every valve keeps a margin")
        base = " (Downs & Vogel base case)" if mode in ("base", "0") else ""
        out[grade_name(mode)] = {
            "setpoints": y0[cvi].tolist(), "mv": mv,
            "description": f"TE mode {grade_name(mode)[4:]}{base}: G/H {ratio} by mass, "
                           f"{rate_text}",
            "g_h_mass_ratio": ratio,
            "product_kg_h": None if rates is None else {"G": rates[0], "H": rates[1]},
            "stability": "unstable"}
    return out
