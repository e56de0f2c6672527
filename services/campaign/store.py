"""The results directory of a campaign (``ssmpc campaign --out DIR``).

Layout::

    DIR/results.json          the campaign document (DESIGN.md shape), rewritten as runs finish
    DIR/runs/<run>.npz        one finished run: its time series and its row
    DIR/report.png            matrix figure: cases x strategies, colour = time to grade or trip
    DIR/report.html           the figure and the table of all runs
    DIR/table.csv             the same table, one row per run

``<run>`` is the run's identity (:mod:`services.campaign.identity`). A run file is a
compressed NumPy archive (:func:`numpy.savez_compressed`; read it with
``numpy.load(path)``) holding

- ``row``: the run's ``results.json`` entry as a JSON string (0-d unicode array);
- ``identity``: the JSON document its identity hashes;
- TE: ``t_h`` (K,) h, ``xmeas`` (K, 41), ``xmv`` (K, 12) %, ``setpoints`` (K, 5)
  (inner loops: T_r*, reactor, separator, stripper level, P_r*), ``ref`` (K, 41)
  the grade references of the XMEAS, ``cost_usd_h`` (K,), ``active`` (K,) model
  index (-1: none), ``model_names``, ``solve_ms`` (K,) controller step time,
  ``constraint_slack`` (K,) (NaN: no MPC solve);
- unit plants: ``t_h``, ``y`` (K, ny) CVs, ``u`` (K, nu) MVs, ``ref`` (K, ntracked),
  ``active``, ``solve_ms``, ``model_names``, ``cv_names``, ``mv_names``.

One row per supervisory sample (TE: 36 s). Every file is written to a temporary
name beside its place and renamed when complete (no half-written file is ever
read as a result); a run file that cannot be read counts as not done. Failed runs
are kept in ``results.json`` only, so the next start with the same ``DIR`` runs
them again, while finished runs (tripped or not) are skipped.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from services.output import atomic_output, to_jsonable

__all__ = ["ResultStore"]


class ResultStore:
    """Run files and the campaign document in one directory."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / "runs"

    def create(self) -> None:
        self.runs_dir.mkdir(parents=True, exist_ok=True)

    def run_path(self, run_id: str) -> Path:
        return self.runs_dir / f"{run_id}.npz"

    def load_row(self, run_id: str) -> dict | None:
        """The stored row of a finished run, or None (absent or unreadable)."""
        path = self.run_path(run_id)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                row = json.loads(str(z["row"][()]))
        except (OSError, ValueError, KeyError, json.JSONDecodeError):
            return None
        if not isinstance(row, dict) or row.get("run") != run_id or row.get("error"):
            return None
        return row

    def load_series(self, run_id: str) -> dict[str, np.ndarray]:
        with np.load(self.run_path(run_id), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def save_run(self, run_id: str, row: dict, series: dict, identity: dict) -> Path:
        """Write one finished run atomically."""
        path = self.run_path(run_id)
        arrays = {k: np.asarray(v) for k, v in series.items()}
        arrays["row"] = np.array(json.dumps(to_jsonable(row), allow_nan=False))
        arrays["identity"] = np.array(json.dumps(identity, sort_keys=True))
        with atomic_output(path, "wb", field="out") as fh:
            np.savez_compressed(fh, **arrays)
        return path

    def save_document(self, doc: dict) -> Path:
        path = self.root / "results.json"
        with atomic_output(path, "w", field="out") as fh:
            json.dump(to_jsonable(doc), fh, indent=1, allow_nan=False)
            fh.write("\n")
        return path
