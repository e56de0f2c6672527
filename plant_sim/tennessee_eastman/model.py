"""The Tennessee Eastman model function (TEFUNC of ``teprob.f``), compiled with numba.

One call of :func:`tefunc` is one evaluation of the original model: it updates
the random processes, computes the 50 time derivatives and the 41 measurements,
adds noise, runs the sampled analyzers and checks the interlocks, in the
original's order and with its floating-point operations in the same order
(no contraction into fused multiply-adds, integer powers as repeated products;
the generator's one explicit fused operation has an exact result, see
:mod:`~plant_sim.tennessee_eastman.random`).

The original keeps state between calls in COMMON blocks (temperature-solver
start values, commanded valve positions, random-process knots, analyzer holds,
generator seed). Here that state is the float64 vector ``mem`` with the layout
below, owned by the caller (one per simulated plant), so the function is
re-entrant and several plants run side by side.

Indices in comments are the original's (1-based); code is 0-based. Functions
are compiled with numba's ``error_model="numpy"``: a division by zero gives
inf/NaN as IEEE arithmetic (and the Fortran original) does, instead of raising.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman.random import advance, draw_signed, noise

__all__ = ["tefunc", "new_memory", "new_work", "NX", "NXMEAS", "NXMV", "NIDV",
           "TRIP_REASONS", "TRIP_LIMITS", "TRIP_VARIABLES"]

NX, NXMEAS, NXMV, NIDV = 50, 41, 12, 20

# ---- layout of ``mem`` (the original's module state plus bookkeeping)
M_TCR, M_TCS, M_TCC, M_TCV = 0, 1, 2, 3  # temperature-solver start values (deg C)
M_VCV = 4  # 12 commanded valve positions (%)
M_ADIST = 16  # 12 each: cubic coefficients and knot times of the random processes
M_BDIST = 28
M_CDIST = 40
M_DDIST = 52
M_TLAST = 64
M_TNEXT = 76
M_XDEL = 88  # 41 analyzer captures (only 23..41 used)
M_TGAS = 129
M_TPROD = 130
M_G = 131  # generator state
M_TIME = 132  # integration time (h), accumulated as the driver does
M_STEPS = 133  # Euler steps taken since t = 0
M_ISD = 134  # trip code of the last evaluation (0: none)
M_TRIP_CODE = 135  # first trip: code, time (h), value of the tripping variable
M_TRIP_TIME = 136
M_TRIP_VALUE = 137
M_FTM13 = 138  # stripper product flow of the last evaluation (lb-mol/h), for the cost
M_SCHED = 139  # next index into an XMV schedule
NMEM = 140

# ---- layout of the scratch vector ``work`` (per-evaluation quantities)
W_XST = 0  # 13 x 8 stream compositions
W_FCM = 104  # 13 x 8 component flows
W_FTM = 208  # 13 stream flows
W_HST = 221  # 13 stream enthalpies
W_TST = 234  # 13 stream temperatures
W_XMWS = 247  # 13 stream molecular weights
W_SFR = 260  # 8 separation factors
W_XLR = 268  # 8 each: reactor liquid, separator liquid, stripper liquid, header vapour
W_XLS = 276
W_XLC = 284
W_XVV = 292
W_PPR = 300  # 8 partial pressures, reactor / separator
W_PPS = 308
W_XCMP = 316  # 41 analyzer compositions
W_WLK = 357  # 12 random-process values at the evaluation time
NWORK = 369

#: Trip codes 1..8 in the order the original checks them: reason, variable, limit.
TRIP_REASONS = ("", "reactor pressure high", "reactor liquid volume high",
                "reactor liquid volume low", "reactor temperature high",
                "separator liquid volume high", "separator liquid volume low",
                "stripper liquid volume high", "stripper liquid volume low")
TRIP_VARIABLES = ("", "XMEAS7 (kPa gauge)", "reactor liquid volume (m3)",
                  "reactor liquid volume (m3)", "XMEAS9 (deg C)",
                  "separator liquid volume (m3)", "separator liquid volume (m3)",
                  "stripper liquid volume (m3)", "stripper liquid volume (m3)")
TRIP_LIMITS = (math.nan, 3000.0, 24.0, 2.0, 175.0, 12.0, 1.0, 8.0, 1.0)


def new_memory(K: np.ndarray, seed: float) -> np.ndarray:
    """Module state of a freshly started original program (TEINIT), generator at ``seed``.

    The temperature-solver start values are 0.0, as in a new process.
    """
    mem = np.zeros(NMEM)
    mem[M_ADIST:M_ADIST + 12] = K[C.SZERO:C.SZERO + 12]
    mem[M_TNEXT:M_TNEXT + 12] = K[C.WLK_FIRST]
    mem[M_G] = seed
    mem[M_TRIP_TIME] = math.nan
    mem[M_TRIP_VALUE] = math.nan
    return mem


def new_work() -> np.ndarray:
    """Scratch space for one plant's evaluations."""
    return np.zeros(NWORK)


# In the enthalpy routines 2.D0, 3.D0 and 1.8D0 are double literals in both
# builds; written inline, the compiler turns the division by 2 into an exact
# multiplication. Components with a mole fraction of exactly zero are skipped:
# their term is a signed zero, which leaves the running sum unchanged.


@njit(cache=True, inline="always", error_model="numpy")
def _enthalpy(K, z, t, ity):
    """Specific enthalpy of a mixture of mole fractions ``z`` at ``t`` deg C (TESUB1).

    ``ity`` 0: liquid, 1: vapour, 2: vapour minus RT (the vapour header).
    """
    h = 0.0
    if ity == 0:
        for i in range(8):
            if z[i] == 0.0:
                continue
            hi = t * (K[C.AH + i] + K[C.BH + i] * t / 2.0 + K[C.CH + i] * (t * t) / 3.0)
            hi = 1.8 * hi
            h = h + z[i] * K[C.XMW + i] * hi
    else:
        for i in range(8):
            if z[i] == 0.0:
                continue
            hi = t * (K[C.AG + i] + K[C.BG + i] * t / 2.0 + K[C.CG + i] * (t * t) / 3.0)
            hi = 1.8 * hi
            hi = hi + K[C.AV + i]
            h = h + z[i] * K[C.XMW + i] * hi
    if ity == 2:
        h = h - K[C.H_GAS_R] * (t + K[C.T_KELVIN])
    return h


@njit(cache=True, inline="always", error_model="numpy")
def _enthalpy_slope(K, z, t, ity):
    """d(enthalpy)/dT of the mixture (TESUB3)."""
    dh = 0.0
    if ity == 0:
        for i in range(8):
            if z[i] == 0.0:
                continue
            dhi = K[C.AH + i] + K[C.BH + i] * t + K[C.CH + i] * (t * t)
            dhi = 1.8 * dhi
            dh = dh + z[i] * K[C.XMW + i] * dhi
    else:
        for i in range(8):
            if z[i] == 0.0:
                continue
            dhi = K[C.AG + i] + K[C.BG + i] * t + K[C.CG + i] * (t * t)
            dhi = 1.8 * dhi
            dh = dh + z[i] * K[C.XMW + i] * dhi
    if ity == 2:
        dh = dh - K[C.H_GAS_R]
    return dh


@njit(cache=True, inline="always", error_model="numpy")
def _temperature(K, z, t_start, h, ity):
    """Temperature whose enthalpy is ``h``, by Newton from ``t_start`` (TESUB2).

    At most 100 iterations; stops when the step is below 1e-12 deg C; if it never
    gets there, the start value is returned, as in the original.
    """
    t = t_start
    for _ in range(100):
        err = _enthalpy(K, z, t, ity) - h
        dt = -err / _enthalpy_slope(K, z, t, ity)
        t = t + dt
        if abs(dt) < 1.0e-12:
            return t
    return t_start


@njit(cache=True, inline="always", error_model="numpy")
def _density(K, x, t):
    """Liquid molar density (lb-mol/ft3) of mole fractions ``x`` at ``t`` deg C (TESUB4)."""
    v = 0.0
    for i in range(8):
        if x[i] == 0.0:
            continue
        v = v + x[i] * K[C.XMW + i] / (K[C.AD + i] + (K[C.BD + i] + K[C.CD + i] * t) * t)
    return K[C.ONE] / v


@njit(cache=True, inline="always", error_model="numpy")
def _walk_value(mem, i, t):
    """Value of random process ``i`` (0-based) at time ``t`` (TESUB8)."""
    h = t - mem[M_TLAST + i]
    return mem[M_ADIST + i] + h * (mem[M_BDIST + i] + h * (mem[M_CDIST + i]
                                                           + h * mem[M_DDIST + i]))


@njit(cache=True, error_model="numpy")
def _update_walks(K, t, idv, mem):
    """Knot updates of the 12 random processes (the draws of step 1 and 2 of te.md 7)."""
    for i in range(12):
        if i < 2:
            flag = idv[7]
        elif i < 6:
            flag = idv[i + 6]
        elif i < 8:
            flag = idv[12]
        elif i == 8:
            flag = idv[15]
        elif i == 9:
            flag = idv[16]
        elif i == 10:
            flag = idv[17]
        else:
            flag = idv[19]
        if t >= mem[M_TNEXT + i]:
            a = mem[M_ADIST + i]
            b = mem[M_BDIST + i]
            c = mem[M_CDIST + i]
            d = mem[M_DDIST + i]
            h = mem[M_TNEXT + i] - mem[M_TLAST + i]
            s = a + h * (b + h * (c + h * d))
            sp = b + h * (2.0 * c + 3.0 * h * d)
            mem[M_TLAST + i] = mem[M_TNEXT + i]
            if i < 9:
                # TESUB5: new Hermite cubic to a random target
                hh = K[C.HSPAN + i] * draw_signed(mem, M_G) + K[C.HZERO + i]
                s1 = K[C.SSPAN + i] * draw_signed(mem, M_G) * flag + K[C.SZERO + i]
                s1p = K[C.SPSPAN + i] * draw_signed(mem, M_G) * flag
                mem[M_ADIST + i] = s
                mem[M_BDIST + i] = sp
                mem[M_CDIST + i] = (3.0 * (s1 - s) - hh * (s1p + 2.0 * sp)) / (hh * hh)
                mem[M_DDIST + i] = (2.0 * (s - s1) + hh * (s1p + sp)) / ((hh * hh) * hh)
                mem[M_TNEXT + i] = mem[M_TLAST + i] + hh
            elif s > K[C.SPIKE_LIM]:
                # decay of a spike back to zero in 0.1 h
                mem[M_ADIST + i] = s
                mem[M_BDIST + i] = sp
                mem[M_CDIST + i] = -(3.0 * s + K[C.SPIKE_B] * sp) / K[C.SPIKE_C]
                mem[M_DDIST + i] = (2.0 * s + K[C.SPIKE_D] * sp) / K[C.SPIKE_E]
                mem[M_TNEXT + i] = mem[M_TLAST + i] + K[C.SPIKE_D]
            else:
                hh = K[C.HSPAN + i] * draw_signed(mem, M_G) + K[C.HZERO + i]
                mem[M_ADIST + i] = 0.0
                mem[M_BDIST + i] = 0.0
                mem[M_CDIST + i] = float(flag) / (hh * hh)
                mem[M_DDIST + i] = 0.0
                mem[M_TNEXT + i] = mem[M_TLAST + i] + hh
    if t == 0.0:
        for i in range(12):
            mem[M_ADIST + i] = K[C.SZERO + i]
            mem[M_BDIST + i] = 0.0
            mem[M_CDIST + i] = 0.0
            mem[M_DDIST + i] = 0.0
            mem[M_TLAST + i] = 0.0
            mem[M_TNEXT + i] = K[C.WLK_FIRST]


@njit(cache=True, error_model="numpy")
def tefunc(K, noise_on, t, yy, xmv, idv, mem, work, xmeas, yp):
    """One evaluation of the model at time ``t`` (h): derivatives, measurements, interlocks.

    Parameters
    ----------
    K : ndarray, shape (NK,)
        Constants of the build (:func:`constants.materialize`).
    noise_on : bool
        Add measurement noise. The random draws happen either way.
    t : float
        Time (h).
    yy : ndarray, shape (50,)
        State.
    xmv : ndarray, shape (12,)
        Manipulated variables (%), not clipped.
    idv : ndarray of int64, shape (20,)
        Disturbance flags (> 0 is on).
    mem : ndarray, shape (NMEM,)
        Persistent model memory (updated).
    work : ndarray, shape (NWORK,)
        Scratch space.
    xmeas : ndarray, shape (41,)
        Measurements (updated; 23..41 hold between analyzer samples).
    yp : ndarray, shape (50,)
        Output: derivatives (state units per hour); all zero while tripped.

    Returns
    -------
    int
        Trip code (0: running; 1..8: index into :data:`TRIP_REASONS`).
    """
    for i in range(20):
        idv[i] = 1 if idv[i] > 0 else 0
    _update_walks(K, t, idv, mem)
    wlk = work[W_WLK:W_WLK + 12]
    for i in range(12):
        wlk[i] = _walk_value(mem, i, t)

    xst = work[W_XST:W_XST + 104].reshape((13, 8))
    fcm = work[W_FCM:W_FCM + 104].reshape((13, 8))
    ftm = work[W_FTM:W_FTM + 13]
    hst = work[W_HST:W_HST + 13]
    tst = work[W_TST:W_TST + 13]
    xmws = work[W_XMWS:W_XMWS + 13]
    sfr = work[W_SFR:W_SFR + 8]
    xlr = work[W_XLR:W_XLR + 8]
    xls = work[W_XLS:W_XLS + 8]
    xlc = work[W_XLC:W_XLC + 8]
    xvv = work[W_XVV:W_XVV + 8]
    ppr = work[W_PPR:W_PPR + 8]
    pps = work[W_PPS:W_PPS + 8]
    xcmp = work[W_XCMP:W_XCMP + 41]

    for i in range(8):
        xst[0, i] = K[C.XST1 + i]
        xst[1, i] = K[C.XST2 + i]
        xst[2, i] = K[C.XST3 + i]
        xst[3, i] = 0.0
    tst[1] = K[C.TST_FEED]
    tst[2] = K[C.TST_FEED]
    xst[3, 0] = wlk[0] - idv[0] * K[C.IDV1_A] - idv[1] * K[C.IDV2_A]
    xst[3, 1] = wlk[1] + idv[1] * K[C.IDV2_B]
    xst[3, 2] = 1.0 - xst[3, 0] - xst[3, 1]
    tst[0] = wlk[2] + idv[2] * K[C.IDV_DT]
    tst[3] = wlk[3]
    tcwr = wlk[4] + idv[3] * K[C.IDV_DT]
    tcws = wlk[5] + idv[4] * K[C.IDV_DT]
    r1f = wlk[6]
    r2f = wlk[7]

    # ---- holdups and compositions
    utlr = 0.0
    utls = 0.0
    utlc = 0.0
    utvv = 0.0
    for i in range(3, 8):
        utlr = utlr + yy[i]
        utls = utls + yy[i + 9]
    for i in range(8):
        utlc = utlc + yy[i + 18]
        utvv = utvv + yy[i + 27]
    for i in range(8):
        xlr[i] = (yy[i] if i >= 3 else 0.0) / utlr
        xls[i] = (yy[i + 9] if i >= 3 else 0.0) / utls
        xlc[i] = yy[i + 18] / utlc
        xvv[i] = yy[i + 27] / utvv
    esr = yy[8] / utlr
    ess = yy[17] / utls
    esc = yy[26] / utlc
    esv = yy[35] / utvv
    tcr = _temperature(K, xlr, mem[M_TCR], esr, 0)
    mem[M_TCR] = tcr
    tkr = tcr + K[C.T_KELVIN]
    tcs = _temperature(K, xls, mem[M_TCS], ess, 0)
    mem[M_TCS] = tcs
    tks = tcs + K[C.T_KELVIN]
    tcc = _temperature(K, xlc, mem[M_TCC], esc, 0)
    mem[M_TCC] = tcc
    tcv = _temperature(K, xvv, mem[M_TCV], esv, 2)
    mem[M_TCV] = tcv
    tkv = tcv + K[C.T_KELVIN]
    dlr = _density(K, xlr, tcr)
    dls = _density(K, xls, tcs)
    dlc = _density(K, xlc, tcc)
    vlr = utlr / dlr
    vls = utls / dls
    vlc = utlc / dlc
    vvr = K[C.VTR] - vlr
    vvs = K[C.VTS] - vls
    rg = K[C.RG]

    # ---- pressures
    ptr = 0.0
    pts = 0.0
    for i in range(3):
        ppr[i] = yy[i] * rg * tkr / vvr
        ptr = ptr + ppr[i]
        pps[i] = yy[i + 9] * rg * tks / vvs
        pts = pts + pps[i]
    for i in range(3, 8):
        vpr = math.exp(K[C.AVP + i] + K[C.BVP + i] / (tcr + K[C.CVP + i]))
        ppr[i] = vpr * xlr[i]
        ptr = ptr + ppr[i]
        vpr = math.exp(K[C.AVP + i] + K[C.BVP + i] / (tcs + K[C.CVP + i]))
        pps[i] = vpr * xls[i]
        pts = pts + pps[i]
    ptv = utvv * rg * tkv / K[C.VTV]

    # ---- reactions
    rr1 = math.exp(K[C.R1_LNK] - K[C.R1_EOR] / tkr) * r1f
    rr2 = math.exp(K[C.R2_LNK] - K[C.R2_EOR] / tkr) * r2f
    rr3 = math.exp(K[C.R3_LNK] - K[C.R3_EOR] / tkr)
    rr4 = rr3 * K[C.R4_RATIO]
    if ppr[0] > 0.0 and ppr[2] > 0.0:
        fa = ppr[0] ** K[C.EXP_PA]
        fc = ppr[2] ** K[C.EXP_PC]
        rr1 = rr1 * fa * fc * ppr[3]
        rr2 = rr2 * fa * fc * ppr[4]
    else:
        rr1 = 0.0
        rr2 = 0.0
    rr3 = rr3 * ppr[0] * ppr[4]
    rr4 = rr4 * ppr[0] * ppr[3]
    rr1 = rr1 * vvr
    rr2 = rr2 * vvr
    rr3 = rr3 * vvr
    rr4 = rr4 * vvr
    rh = rr1 * K[C.HTR] + rr2 * K[C.HTR + 1]

    # ---- stream compositions, molecular weights, enthalpies
    for i in range(8):
        xst[5, i] = xvv[i]
        xst[7, i] = ppr[i] / ptr
        xst[8, i] = pps[i] / pts
        xst[9, i] = xst[8, i]
        xst[10, i] = xls[i]
        xst[12, i] = xlc[i]
    for k in (0, 1, 5, 7, 8, 9):
        m = 0.0
        for i in range(8):
            m = m + xst[k, i] * K[C.XMW + i]
        xmws[k] = m
    tst[5] = tcv
    tst[7] = tcr
    tst[8] = tcs
    tst[9] = tcs
    tst[10] = tcs
    tst[12] = tcc
    for k in (0, 1, 2, 3, 5, 7, 8):
        hst[k] = _enthalpy(K, xst[k], tst[k], 1)
    hst[9] = hst[8]
    hst[10] = _enthalpy(K, xst[10], tst[10], 0)
    hst[12] = _enthalpy(K, xst[12], tst[12], 0)

    # ---- flows
    vpos = yy[38:50]
    pct = K[C.PCT]
    ftm[0] = vpos[0] * K[C.VRNG] / pct
    ftm[1] = vpos[1] * K[C.VRNG + 1] / pct
    ftm[2] = vpos[2] * (1.0 - idv[5]) * K[C.VRNG + 2] / pct
    ftm[3] = vpos[3] * (1.0 - idv[6] * K[C.IDV7_F]) * K[C.VRNG + 3] / pct + K[C.FTM4_EPS]
    ftm[10] = vpos[6] * K[C.VRNG + 6] / pct
    ftm[12] = vpos[7] * K[C.VRNG + 7] / pct
    uac = vpos[8] * K[C.VRNG + 8] * (1.0 + wlk[8]) / pct
    fwr = vpos[9] * K[C.VRNG + 9] / pct
    fws = vpos[10] * K[C.VRNG + 10] / pct
    agsp = (vpos[11] + K[C.AGSP_OFFSET]) / pct
    dlp = ptv - ptr
    if dlp < 0.0:
        dlp = 0.0
    flms = K[C.K_FEED_FLOW] * math.sqrt(dlp)
    ftm[5] = flms / xmws[5]
    dlp = ptr - pts
    if dlp < 0.0:
        dlp = 0.0
    flms = K[C.K_EFFLUENT_FLOW] * math.sqrt(dlp) * (1.0 - K[C.W_SPIKE_EFFLUENT] * wlk[11])
    ftm[7] = flms / xmws[7]
    dlp = pts - K[C.P_ATM]
    if dlp < 0.0:
        dlp = 0.0
    flms = vpos[5] * K[C.K_PURGE_FLOW] * math.sqrt(dlp)
    ftm[9] = flms / xmws[9]
    pr = ptv / pts
    if pr < K[C.ONE]:
        pr = K[C.ONE]
    if pr > K[C.CPPRMX]:
        pr = K[C.CPPRMX]
    flcoef = K[C.CPFLMX] / K[C.CP_FLCOEF_DIV]
    flms = K[C.CPFLMX] + flcoef * (K[C.ONE] - pr * pr * pr)
    cpdh = (flms * (tcs + K[C.T_KELVIN_D]) * K[C.CP_WORK_A] * K[C.CP_WORK_B]
            * (ptv - pts) / (xmws[8] * pts))
    dlp = ptv - pts
    if dlp < 0.0:
        dlp = 0.0
    flms = flms - vpos[4] * K[C.K_RECYCLE_FLOW] * math.sqrt(dlp)
    if flms < K[C.FLMS_MIN]:
        flms = K[C.FLMS_MIN]
    ftm[8] = flms / xmws[8]
    hst[8] = hst[8] + cpdh / ftm[8]
    for k in (0, 1, 2, 3, 5, 7, 8, 9, 10, 12):
        for i in range(8):
            fcm[k, i] = xst[k, i] * ftm[k]

    # ---- stripper separation
    for i in range(3):
        sfr[i] = K[C.SFR_ABC + i]
    if ftm[10] > K[C.FTM11_MIN]:
        if tcc > K[C.TCC_HI]:
            tmpfac = tcc - K[C.TMPFAC_HI_OFF]
        elif tcc < K[C.TCC_LO]:
            tmpfac = K[C.TMPFAC_LO]
        else:
            tmpfac = K[C.TMPFAC_NUM] / (K[C.TMPFAC_DEN] - tcc) - K[C.TMPFAC_OFF]
        vovrl = ftm[3] / ftm[10] * tmpfac
        for j in range(5):
            sfr[3 + j] = K[C.SFR_K + j] * vovrl / (K[C.ONE] + K[C.SFR_K + j] * vovrl)
    else:
        for j in range(5):
            sfr[3 + j] = K[C.SFR_FALLBACK + j]
    ftm[4] = 0.0
    ftm[11] = 0.0
    for i in range(8):
        fin = 0.0 + fcm[3, i] + fcm[10, i]
        fcm[4, i] = sfr[i] * fin
        fcm[11, i] = fin - fcm[4, i]
        ftm[4] = ftm[4] + fcm[4, i]
        ftm[11] = ftm[11] + fcm[11, i]
    for i in range(8):
        xst[4, i] = fcm[4, i] / ftm[4]
        xst[11, i] = fcm[11, i] / ftm[11]
    tst[4] = tcc
    tst[11] = tcc
    hst[4] = _enthalpy(K, xst[4], tst[4], 1)
    hst[11] = _enthalpy(K, xst[11], tst[11], 0)
    ftm[6] = ftm[5]
    hst[6] = hst[5]
    tst[6] = tst[5]
    for i in range(8):
        xst[6, i] = xst[5, i]
        fcm[6, i] = fcm[5, i]

    # ---- heat transfer
    if vlr / K[C.VLR_SCALE] > K[C.UARLEV_HI]:
        uarlev = K[C.ONE]
    elif vlr / K[C.VLR_SCALE] < K[C.UARLEV_LO]:
        uarlev = 0.0
    else:
        uarlev = K[C.UARLEV_SLOPE] * vlr / K[C.VLR_SCALE] - K[C.UARLEV_OFF]
    uar = (uarlev * (-(K[C.AG_C2] * (agsp * agsp)) + K[C.AG_C1] * agsp - K[C.AG_C0])
           * K[C.UAR_SCALE])
    qur = uar * (yy[36] - tcr) * (1.0 - K[C.W_SPIKE_REACTOR] * wlk[9])
    x = ftm[7] / K[C.UAS_F]
    uas = K[C.UAS_A] * (K[C.ONE] - K[C.ONE] / (K[C.ONE] + (x * x) * (x * x)))
    qus = uas * (yy[37] - tst[7]) * (1.0 - K[C.W_SPIKE_CONDENSER] * wlk[10])
    quc = 0.0
    if tcc < K[C.TCC_STEAM]:
        quc = uac * (K[C.TCC_STEAM] - tcc)

    # ---- continuous measurements
    scm = K[C.SCM_PER_LBMOL]
    f3 = K[C.FT3_PER_M3]
    patm = K[C.P_ATM]
    kpa = K[C.KPA_PER_ATM]
    xmeas[0] = ftm[2] * scm / f3
    xmeas[1] = ftm[0] * xmws[0] * K[C.KG_PER_LB]
    xmeas[2] = ftm[1] * xmws[1] * K[C.KG_PER_LB]
    xmeas[3] = ftm[3] * scm / f3
    xmeas[4] = ftm[8] * scm / f3
    xmeas[5] = ftm[5] * scm / f3
    xmeas[6] = (ptr - patm) / patm * kpa
    xmeas[7] = (vlr - K[C.RLEV_OFF]) / K[C.RLEV_SPAN] * pct
    xmeas[8] = tcr
    xmeas[9] = ftm[9] * scm / f3
    xmeas[10] = tcs
    xmeas[11] = (vls - K[C.SLEV_OFF]) / K[C.SLEV_SPAN] * pct
    xmeas[12] = (pts - patm) / patm * kpa
    xmeas[13] = ftm[10] / dls / f3
    xmeas[14] = (vlc - K[C.CLEV_OFF]) / K[C.VTC] * pct
    xmeas[15] = (ptv - patm) / patm * kpa
    xmeas[16] = ftm[12] / dlc / f3
    xmeas[17] = tcc
    xmeas[18] = quc * K[C.STEAM_A] * K[C.KG_PER_LB]
    xmeas[19] = cpdh * K[C.WORK_KW]
    xmeas[20] = yy[36]
    xmeas[21] = yy[37]
    mem[M_FTM13] = ftm[12]

    # ---- interlocks, checked on noise-free values; the first limit in the
    # original's order is reported
    isd = 0
    if xmeas[6] > K[C.LIM_PR]:
        isd = 1
    elif vlr / f3 > K[C.LIM_VLR_HI]:
        isd = 2
    elif vlr / f3 < K[C.LIM_VLR_LO]:
        isd = 3
    elif xmeas[8] > K[C.LIM_TR]:
        isd = 4
    elif vls / f3 > K[C.LIM_VLS_HI]:
        isd = 5
    elif vls / f3 < K[C.LIM_VLS_LO]:
        isd = 6
    elif vlc / f3 > K[C.LIM_VLC_HI]:
        isd = 7
    elif vlc / f3 < K[C.LIM_VLC_LO]:
        isd = 8
    if isd != 0 and mem[M_TRIP_CODE] == 0.0:
        mem[M_TRIP_CODE] = isd
        mem[M_TRIP_TIME] = t
        if isd == 1:
            mem[M_TRIP_VALUE] = xmeas[6]
        elif isd == 4:
            mem[M_TRIP_VALUE] = xmeas[8]
        elif isd <= 3:
            mem[M_TRIP_VALUE] = vlr / f3
        elif isd <= 6:
            mem[M_TRIP_VALUE] = vls / f3
        else:
            mem[M_TRIP_VALUE] = vlc / f3
    mem[M_ISD] = isd

    if t > 0.0 and isd == 0:
        if noise_on:
            for i in range(22):
                xmeas[i] = xmeas[i] + noise(mem, M_G, K[C.XNS + i])
        else:
            advance(mem, M_G, 22 * 12)

    # ---- sampled analyzers
    for i in range(6):
        xcmp[22 + i] = xst[6, i] * pct
    for i in range(8):
        xcmp[28 + i] = xst[9, i] * pct
    for i in range(5):
        xcmp[36 + i] = xst[12, 3 + i] * pct
    if t == 0.0:
        for i in range(22, 41):
            mem[M_XDEL + i] = xcmp[i]
            xmeas[i] = xcmp[i]
        mem[M_TGAS] = K[C.TGAS_PERIOD]
        mem[M_TPROD] = K[C.TPROD_PERIOD]
    if t >= mem[M_TGAS]:
        for i in range(22, 36):
            xmeas[i] = mem[M_XDEL + i]
            if noise_on:
                xmeas[i] = xmeas[i] + noise(mem, M_G, K[C.XNS + i])
            else:
                advance(mem, M_G, 12)
            mem[M_XDEL + i] = xcmp[i]
        mem[M_TGAS] = mem[M_TGAS] + K[C.TGAS_PERIOD]
    if t >= mem[M_TPROD]:
        for i in range(36, 41):
            xmeas[i] = mem[M_XDEL + i]
            if noise_on:
                xmeas[i] = xmeas[i] + noise(mem, M_G, K[C.XNS + i])
            else:
                advance(mem, M_G, 12)
            mem[M_XDEL + i] = xcmp[i]
        mem[M_TPROD] = mem[M_TPROD] + K[C.TPROD_PERIOD]

    # ---- derivatives
    for i in range(8):
        crxr = 0.0
        if i == 0:
            crxr = -rr1 - rr2 - rr3
        elif i == 2:
            crxr = -rr1 - rr2
        elif i == 3:
            crxr = -rr1 - K[C.D_STOICH] * rr4
        elif i == 4:
            crxr = -rr2 - rr3
        elif i == 5:
            crxr = rr3 + rr4
        elif i == 6:
            crxr = rr1
        elif i == 7:
            crxr = rr2
        yp[i] = fcm[6, i] - fcm[7, i] + crxr
        yp[i + 9] = fcm[7, i] - fcm[8, i] - fcm[9, i] - fcm[10, i]
        yp[i + 18] = fcm[11, i] - fcm[12, i]
        yp[i + 27] = fcm[0, i] + fcm[1, i] + fcm[2, i] + fcm[4, i] + fcm[8, i] - fcm[5, i]
    yp[8] = hst[6] * ftm[6] - hst[7] * ftm[7] + rh + qur
    yp[17] = hst[7] * ftm[7] - hst[8] * ftm[8] - hst[9] * ftm[9] - hst[10] * ftm[10] + qus
    yp[26] = hst[3] * ftm[3] + hst[10] * ftm[10] - hst[4] * ftm[4] - hst[12] * ftm[12] + quc
    yp[35] = (hst[0] * ftm[0] + hst[1] * ftm[1] + hst[2] * ftm[2] + hst[4] * ftm[4]
              + hst[8] * ftm[8] - hst[5] * ftm[5])
    yp[36] = (fwr * K[C.CW_CP] * (tcwr - yy[36]) - qur * K[C.Q_SCALE] / K[C.Q_DIV]) / K[C.HWR]
    yp[37] = (fws * K[C.CW_CP] * (tcws - yy[37]) - qus * K[C.Q_SCALE] / K[C.Q_DIV]) / K[C.HWS]

    # ---- valves: sticking dead band (IDV 14, 15, 19), clipping of the command, lag
    for i in range(12):
        ivst = 0
        if i == 9:
            ivst = idv[13]
        elif i == 10:
            ivst = idv[14]
        elif i == 4 or i == 6 or i == 7 or i == 8:
            ivst = idv[18]
        vcv = mem[M_VCV + i]
        if t == 0.0 or abs(vcv - xmv[i]) > K[C.VST] * ivst:
            vcv = xmv[i]
        if vcv < 0.0:
            vcv = 0.0
        if vcv > pct:
            vcv = pct
        mem[M_VCV + i] = vcv
        yp[38 + i] = (vcv - vpos[i]) / (K[C.VTAU + i] / K[C.S_PER_H])

    if isd != 0:
        for i in range(NX):
            yp[i] = 0.0
    return isd
