"""Start states of the Tennessee Eastman plant: the base case and Ricker's modes 1-6.

- ``base`` (grade ``mode0``): the published initial state of TEINIT, as the chosen
  literal build sees it (float32-rounded in the published build).
- ``1`` ... ``6`` (grades ``mode1`` ... ``mode6``): the optimal steady states of
  N. L. Ricker, "Optimal steady-state operation of the Tennessee Eastman challenge
  process", Comput. Chem. Eng. 19 (1995) 949-959, 50 states to about 7 digits
  (``ricker1995_steady_states.csv``, a copy of the facts file). States 39-50 are
  the valve positions; the XMVs start equal to them.

Ricker's states are steady for his solution of the model, not to the last digit
of this code: started there open loop, the plant drifts (and with the
published base case it trips after about 4 h).
"""

from __future__ import annotations

import csv
from functools import lru_cache
from importlib import resources

import numpy as np

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import constants as C

__all__ = ["MODES", "start_state", "grade_name", "parse_mode"]

#: Accepted mode names, in order.
MODES = ("base", "1", "2", "3", "4", "5", "6")
_CSV = "ricker1995_steady_states.csv"


@lru_cache(maxsize=1)
def _ricker_table() -> dict[str, np.ndarray]:
    text = resources.files("plant_sim.tennessee_eastman").joinpath(_CSV).read_text()
    rows = list(csv.reader(text.splitlines()))
    header, body = rows[0], rows[1:]
    if len(body) != 50 or header[0] != "state":
        raise RuntimeError(f"{_CSV}: expected 50 state rows, got {len(body)}")
    cols = {name: np.array([float(r[j]) for r in body]) for j, name in enumerate(header)
            if j > 0}
    return cols


def parse_mode(mode) -> str:
    """Normalize a mode name: ``base``/``0``/``mode0`` -> ``base``, ``3``/``mode3`` -> ``3``.

    Raises
    ------
    PlantInputError
        For an unknown mode; the message lists the known ones.
    """
    text = str(mode).strip().lower()
    if text.startswith("mode"):
        text = text[4:]
    if text in ("0", "base"):
        return "base"
    if text in MODES:
        return text
    raise PlantInputError(f"mode: unknown mode {mode!r}; known: {', '.join(MODES)} "
                          f"(or mode0..mode6)")


def grade_name(mode) -> str:
    """The grade name of a mode (``mode0`` ... ``mode6``)."""
    m = parse_mode(mode)
    return "mode0" if m == "base" else f"mode{m}"


def start_state(mode="base", literals: str = "single") -> np.ndarray:
    """Initial state (50,) of a mode; the XMVs start equal to states 39-50.

    Parameters
    ----------
    mode : str or int
        ``base`` (or 0) or 1..6.
    literals : {"single", "double"}
        Literal build; affects only the base case (the published literals).
    """
    m = parse_mode(mode)
    if m == "base":
        return C.get("YY0", literals)
    return _ricker_table()[f"mode{m}"].copy()
