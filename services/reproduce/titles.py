"""One line per seed result: what ``ssmpc reproduce ID`` compares (the seed's section,
table or figure), and the verdicts of earlier runs on this machine.

The verdicts are a convenience of ``ssmpc reproduce list``: the last verdict of each
result, kept in ``$XDG_CACHE_HOME/ssmpc/reproduce-verdicts.json`` (default
``~/.cache``), written atomically after each run. Nothing else reads them.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

__all__ = ["TITLES", "last_verdicts", "record_verdict"]

TITLES = {
    "R3.0": "state-shared model: parameter counts, exact Theta, truncation stability (ch. 3)",
    "R3.1": "two-phase reactor: full-order linearizations at OPI and OPII (§3.3)",
    "R3.2": "two-phase reactor: order-2 balanced truncations and Re (eq. 3.22)",
    "R3.3": "two-phase reactor: ARe of the reduced models, Table 3.3",
    "R3.4": "two-phase reactor: state-shared model structure",
    "R3.5": "two-phase reactor: the printed Theta of model 1 (OPI)",
    "R3.6": "two-phase reactor: state-shared model against the nonlinear plant",
    "R3.7": "calcium (CICR): linearizations",
    "R3.8": "calcium: Re of the balanced truncations",
    "R3.9": "calcium: ARe of the order-3 models",
    "R3.10": "calcium: ARe, Table 3.6",
    "R3.11": "calcium: state-shared model structure",
    "R4.1": "model set and adaptation properties (ch. 4)",
    "R5.1": "CSTR operating points",
    "R5.2": "CSTR transfer functions, Table 5.3",
    "R5.3": "CSTR MRAC transition OPI -> OPII, Fig. 5.3",
    "R5.4": "CSTR model parameters under MRAC, Table 5.4",
    "R5.5": "CSTR H-infinity with multiple models, OPI <-> OPII, Figs. 5.12-5.13",
    "R5.6": "CSTR model parameters after OPI -> OPII (H-infinity), Table 5.6",
    "R5.7": "CSTR robustness tests, Fig. 5.15 and Table 5.7",
    "R5.8": "CSTR multiple transitions 1.3 -> 2 -> 5 -> 1.3, Table 5.8",
    "R5.9": "bioreactor steady states and linear models, Table 5.10",
    "R5.10": "bioreactor H-infinity transitions 0 <-> 0.389, Figs. 5.18-5.19",
    "R5.11": "bioreactor modelling error, Fig. 5.20",
    "R5.12": "CSTR: state-shared against a single fixed model, Fig. 5.21",
    "R5.13": "bioreactor: state-shared against a single model, Fig. 5.22",
    "R6.0": "MPC formulation (eqs. 6.3-6.10)",
    "R6.1": "two-phase reactor MPC: F4 100 -> 130 kmol/h, Fig. 6.1",
    "R6.2": "the same transition with measurement noise, Fig. 6.2",
    "R6.3": "the same transition with yA3 inferred, Fig. 6.3",
    "R6.4": "squared errors with yA3 measured and inferred, Table 6.1",
    "R6.5": "calcium 2x2 linear models for the MPC",
    "R6.6": "calcium MPC transitions, Figs. 6.4-6.5",
    "R7.1": "TE modes of operation, Table 7.1",
    "R7.3": "TE measured outputs per mode, Table 7.3",
    "R7.8": "TE operating cost (Downs & Vogel)",
    "R7.9": "TE model constants of chapter 7",
    "R7.10": "TE open-loop linearization at the base case",
    "R7.11": "TE inner PI loops, Table 7.10",
    "R7.12": "TE fixed-model MPC settings (§7.4.2)",
    "R7.13": "TE IDV(6) A-feed loss at mode 3, fixed models + MPC, Figs. 7.3-7.6",
    "R7.14": "TE mode 0 -> 2 and 0 -> 2 -> 3, fixed models + MPC, Figs. 7.7-7.13",
    "R7.15": "TE state-shared MPC structure (§7.7)",
    "R7.16": "TE state-shared MPC mode 0 -> 2, Figs. 7.14-7.16",
}


def _path() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ssmpc" / "reproduce-verdicts.json"


def last_verdicts() -> dict[str, dict]:
    """``{id: {"verdict", "at"}}`` of earlier runs; empty when none or unreadable."""
    try:
        data = json.loads(_path().read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def record_verdict(rid: str, verdict: str) -> None:
    """Keep ``verdict`` as the last one of ``rid`` (atomic replace; failures ignored)."""
    path = _path()
    data = last_verdicts()
    data[rid] = {"verdict": verdict, "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".verdicts-")
        with os.fdopen(fd, "w") as fh:
            json.dump(data, fh, indent=1, sort_keys=True)
        os.replace(tmp, path)
    except OSError:
        pass
