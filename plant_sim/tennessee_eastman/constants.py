"""Numeric literals of the Tennessee Eastman model, each declared once.

Every literal is written in its Fortran spelling in ``teprob.f`` (Downs & Vogel
1993). The spelling decides its precision, exactly as the Fortran compiler does:
a literal with a ``D`` exponent is double precision, any other real literal is
single precision (REAL*4) and is rounded to float32 before it meets a double
operand. An entry ``"a/b"`` is a quotient of two literals that the compiler folds
at compile time (in float32 when both are single).

:func:`materialize` turns the table into one float64 vector ``K`` for the
compiled model, either as the published build does (``"single"``) or with every
literal taken as a double (``"double"``). The model indexes ``K`` with the
integer offsets defined below as module attributes (``K[RG]``,
``K[XMW + i]``, ...).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["LITERAL_MODES", "materialize", "literal_value", "TABLE", "NK"]

LITERAL_MODES = ("single", "double")

#: (name, Fortran spelling(s)). Names are the Fortran variable or a short
#: description of the role of the literal. Whitespace separates vector entries.
TABLE: tuple[tuple[str, str], ...] = (
    # ---- physical constants and unit conversions
    ("T_KELVIN", "273.15"),  # Kelvin offset in TKR, TKS, TKV and the gas-header enthalpy
    ("T_KELVIN_D", "273.15D0"),  # the one Kelvin offset written as a double (compressor work)
    ("RG", "998.9"),  # gas constant, mmHg ft3 / (lb-mol K)
    ("P_ATM", "760.0"),
    ("KPA_PER_ATM", "101.325"),
    ("SCM_PER_LBMOL", "0.359"),
    ("FT3_PER_M3", "35.3145"),
    ("KG_PER_LB", "0.454"),
    # ---- reaction kinetics
    ("R1_LNK", "31.5859536"),
    ("R1_EOR", "40000.0/1.987"),
    ("R2_LNK", "3.00094014"),
    ("R2_EOR", "20000.0/1.987"),
    ("R3_LNK", "53.4060443"),
    ("R3_EOR", "60000.0/1.987"),
    ("R4_RATIO", "0.767488334D0"),
    ("EXP_PA", "1.1544"),
    ("EXP_PC", "0.3735"),
    ("D_STOICH", "1.5D0"),
    ("HTR", "0.06899381054D0 0.05D0"),
    # ---- vessels, valves, flow correlations
    ("VTR", "1300.0"),
    ("VTS", "3500.0"),
    ("VTC", "156.5"),
    ("VTV", "5000.0"),
    ("VRNG", "400.00 400.00 100.00 1500.00 0.0 0.0 1500.00 1000.00 0.03 1000. 1200.0 0.0"),
    ("VTAU", "8. 8. 6. 9. 7. 5. 5. 5. 120. 5. 5. 5."),
    ("S_PER_H", "3600."),
    ("VST", "2.0D0"),
    ("PCT", "100.0"),
    ("AGSP_OFFSET", "150.0"),
    ("FTM4_EPS", "1.D-10"),
    ("K_FEED_FLOW", "1937.6D0"),
    ("K_EFFLUENT_FLOW", "4574.21D0"),
    ("K_PURGE_FLOW", "0.151169D0"),
    ("K_RECYCLE_FLOW", "53.349D0"),
    ("CPFLMX", "280275."),
    ("CPPRMX", "1.3"),
    ("CP_FLCOEF_DIV", "1.197D0"),
    ("CP_WORK_A", "1.8D-6"),
    ("CP_WORK_B", "1.9872D0"),
    ("FLMS_MIN", "1.D-3"),
    ("W_SPIKE_EFFLUENT", "0.25D0"),
    ("W_SPIKE_REACTOR", "0.35D0"),
    ("W_SPIKE_CONDENSER", "0.25D0"),
    # ---- stripper separation factors
    ("FTM11_MIN", "0.1"),
    ("TCC_HI", "170."),
    ("TMPFAC_HI_OFF", "120.262"),
    ("TCC_LO", "5.292"),
    ("TMPFAC_LO", "0.1"),
    ("TMPFAC_NUM", "363.744"),
    ("TMPFAC_DEN", "177."),
    ("TMPFAC_OFF", "2.22579488"),
    ("SFR_K", "8.5010 11.402 11.795 0.0480 0.0242"),
    ("SFR_FALLBACK", "0.9999 0.999 0.999 0.99 0.98"),
    ("SFR_ABC", "0.99500 0.99100 0.99000"),
    ("ONE", "1.0"),
    # ---- heat transfer
    ("VLR_SCALE", "7.8"),
    ("UARLEV_HI", "50.0"),
    ("UARLEV_LO", "10.0"),
    ("UARLEV_SLOPE", "0.025"),
    ("UARLEV_OFF", "0.25"),
    ("AG_C2", "0.5"),
    ("AG_C1", "2.75"),
    ("AG_C0", "2.5"),
    ("UAR_SCALE", "855490.D-6"),
    ("UAS_A", "0.404655"),
    ("UAS_F", "3528.73"),
    ("TCC_STEAM", "100."),
    ("CW_CP", "500.53"),
    ("Q_SCALE", "1.D6"),
    ("Q_DIV", "1.8"),
    ("HWR", "7060."),
    ("HWS", "11138."),
    # ---- measurements
    ("RLEV_OFF", "84.6"),
    ("RLEV_SPAN", "666.7"),
    ("SLEV_OFF", "27.5"),
    ("SLEV_SPAN", "290.0"),
    ("CLEV_OFF", "78.25"),
    ("STEAM_A", "1.04D3"),
    ("WORK_KW", "0.29307D3"),
    ("TGAS_PERIOD", "0.1"),
    ("TPROD_PERIOD", "0.25"),
    # ---- interlock limits
    ("LIM_PR", "3000.0"),
    ("LIM_VLR_HI", "24.0"),
    ("LIM_VLR_LO", "2.0"),
    ("LIM_TR", "175.0"),
    ("LIM_VLS_HI", "12.0"),
    ("LIM_VLS_LO", "1.0"),
    ("LIM_VLC_HI", "8.0"),
    ("LIM_VLC_LO", "1.0"),
    # ---- component properties (TEINIT, COMMON /CONST/)
    ("XMW", "2.0 25.4 28.0 32.0 46.0 48.0 62.0 76.0"),
    ("AVP", "0.0 0.0 0.0 15.92 16.35 16.35 16.43 17.21"),
    ("BVP", "0.0 0.0 0.0 -1444.0 -2114.0 -2114.0 -2748.0 -3318.0"),
    ("CVP", "0.0 0.0 0.0 259.0 265.5 265.5 232.9 249.6"),
    ("AD", "1.0 1.0 1.0 23.3 33.9 32.8 49.9 50.5"),
    ("BD", "0.0 0.0 0.0 -0.0700 -0.0957 -0.0995 -0.0191 -0.0541"),
    ("CD", "0.0 0.0 0.0 -0.0002 -0.000152 -0.000233 -0.000425 -0.000150"),
    ("AH", "1.0D-6 1.0D-6 1.0D-6 0.960D-6 0.573D-6 0.652D-6 0.515D-6 0.471D-6"),
    ("BH", "0.0 0.0 0.0 8.70D-9 2.41D-9 2.18D-9 5.65D-10 8.70D-10"),
    ("CH", "0.0 0.0 0.0 4.81D-11 1.82D-11 1.94D-11 3.82D-12 2.62D-12"),
    ("AV", "1.0D-6 1.0D-6 1.0D-6 86.7D-6 160.D-6 160.D-6 225.D-6 209.D-6"),
    ("AG", "3.411D-6 0.3799D-6 0.2491D-6 0.3567D-6 0.3463D-6 0.3930D-6 0.170D-6 0.150D-6"),
    ("BG", "7.18D-10 1.08D-9 1.36D-11 8.51D-10 8.96D-10 1.02D-9 0.D0 0.D0"),
    ("CG", "6.0D-13 -3.98D-13 -3.93D-14 -3.12D-13 -3.27D-13 -3.12D-13 0.D0 0.D0"),
    ("H_GAS_R", "3.57696D0/1.D6"),
    # ---- feed streams 1-3 compositions (stream 4's A, B, C come from the random processes)
    ("XST1", "0.0 0.0001 0.0 0.9999 0.0 0.0 0.0 0.0"),
    ("XST2", "0.0 0.0 0.0 0.0 0.9999 0.0001 0.0 0.0"),
    ("XST3", "0.9999 0.0001 0.0 0.0 0.0 0.0 0.0 0.0"),
    ("TST_FEED", "45."),
    # ---- disturbances (IDV 1-7 steps)
    ("IDV1_A", "0.03D0"),
    ("IDV2_A", "2.43719D-3"),
    ("IDV2_B", "0.005D0"),
    ("IDV_DT", "5.D0"),
    ("IDV7_F", "0.2D0"),
    # ---- random processes w1..w12 (TEINIT)
    ("HSPAN", "0.2D0 0.7D0 0.25D0 0.7D0 0.15D0 0.15D0 1.D0 1.D0 0.4D0 1.5D0 2.0D0 1.5D0"),
    ("HZERO", "0.5D0 1.0D0 0.5D0 1.0D0 0.25D0 0.25D0 2.D0 2.D0 0.5D0 2.0D0 3.0D0 2.0D0"),
    ("SSPAN", "0.03D0 .003D0 10.D0 10.D0 10.D0 10.D0 0.25D0 0.25D0 0.25D0 0.0D0 0.0D0 0.0D0"),
    ("SZERO", "0.485D0 .005D0 45.D0 45.D0 35.D0 40.D0 1.0D0 1.0D0 0.0D0 0.0D0 0.0D0 0.0D0"),
    ("SPSPAN", "0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0 0.D0"),
    ("WLK_FIRST", "0.1D0"),
    ("SPIKE_LIM", "0.1D0"),
    ("SPIKE_B", "0.2D0"),
    ("SPIKE_C", "0.01D0"),
    ("SPIKE_D", "0.1D0"),
    ("SPIKE_E", "0.001D0"),
    # ---- measurement noise standard deviations XNS(1..41)
    ("XNS", "0.0012D0 18.000D0 22.000D0 0.0500D0 0.2000D0 0.2100D0 0.3000D0 0.5000D0 "
            "0.0100D0 0.0017D0 0.0100D0 1.0000D0 0.3000D0 0.1250D0 1.0000D0 0.3000D0 "
            "0.1150D0 0.0100D0 1.1500D0 0.2000D0 0.0100D0 0.0100D0 0.250D0 0.100D0 0.250D0 "
            "0.100D0 0.250D0 0.025D0 0.250D0 0.100D0 0.250D0 0.100D0 0.250D0 0.025D0 "
            "0.050D0 0.050D0 0.010D0 0.010D0 0.010D0 0.500D0 0.500D0"),
    # ---- published initial state YY(1..50) (TEINIT); 20, 22 and 24 are double literals
    ("YY0", "10.40491389 4.363996017 7.570059737 0.4230042431 24.15513437 2.942597645 "
            "154.3770655 159.1865960 2.808522723 63.75581199 26.74026066 46.38532432 "
            "0.2464521543 15.20484404 1.852266172 52.44639459 41.20394008 0.5699317760 "
            "0.4306056376 7.9906200783D-03 0.9056036089 1.6054258216D-02 0.7509759687 "
            "8.8582855955D-02 48.27726193 39.38459028 0.3755297257 107.7562698 "
            "29.77250546 88.32481135 23.03929507 62.85848794 5.546318688 11.92244772 "
            "5.555448243 0.9218489762 94.59927549 77.29698353 63.05263039 53.97970677 "
            "24.64355755 61.30192144 22.21000000 40.06374673 38.10034370 46.53415582 "
            "47.44573456 41.10581288 18.11349055 50.00000000"),
)


def _is_double(text: str) -> bool:
    return "D" in text.upper()


def _scalar(text: str, literals: str) -> float:
    """Value of one Fortran literal as the chosen build sees it."""
    value = float(text.upper().replace("D", "e"))
    if literals == "single" and not _is_double(text):
        return float(np.float32(value))
    return value


def literal_value(text: str, literals: str = "single") -> float:
    """Value of a Fortran literal (or a folded ``a/b`` of two literals) in a build.

    Parameters
    ----------
    text : str
        Fortran spelling, e.g. ``"273.15"``, ``"0.767488334D0"``, ``"40000.0/1.987"``.
    literals : {"single", "double"}
        ``"single"``: the published build (literals without a D exponent are REAL*4,
        and a quotient of two such literals is folded in float32);
        ``"double"``: every literal is a double.
    """
    if literals not in LITERAL_MODES:
        raise ValueError(f"literals: expected one of {LITERAL_MODES}, got {literals!r}")
    if "/" in text:
        num, den = text.split("/")
        if literals == "single" and not _is_double(num) and not _is_double(den):
            return float(np.float32(np.float32(_scalar(num, literals))
                                    / np.float32(_scalar(den, literals))))
        return _scalar(num, literals) / _scalar(den, literals)
    return _scalar(text, literals)


def _layout() -> tuple[dict[str, int], dict[str, int], int]:
    offsets: dict[str, int] = {}
    sizes: dict[str, int] = {}
    n = 0
    for name, spelling in TABLE:
        if name in offsets:
            raise RuntimeError(f"constants: duplicate name {name}")
        count = len(spelling.split())
        offsets[name] = n
        sizes[name] = count
        n += count
    return offsets, sizes, n


OFFSETS, SIZES, NK = _layout()
globals().update(OFFSETS)  # K offsets as module attributes: constants.RG, constants.XMW, ...


@lru_cache(maxsize=2)
def _materialize(literals: str) -> np.ndarray:
    values = []
    for _name, spelling in TABLE:
        values.extend(literal_value(t, literals) for t in spelling.split())
    k = np.array(values, dtype=np.float64)
    k.setflags(write=False)
    return k


def materialize(literals: str = "single") -> np.ndarray:
    """The constant vector ``K`` (float64, shape ``(NK,)``) of a build; read-only.

    Raises
    ------
    ValueError
        If ``literals`` is not ``"single"`` or ``"double"``.
    """
    if literals not in LITERAL_MODES:
        raise ValueError(f"literals: expected one of {', '.join(LITERAL_MODES)}, got {literals!r}")
    return _materialize(literals)


def get(name: str, literals: str = "single") -> np.ndarray:
    """The entries of one table row as a float array (a copy)."""
    k = materialize(literals)
    return k[OFFSETS[name]:OFFSETS[name] + SIZES[name]].copy()
