"""The TE cascade's moves against stored ones (``tests/data/te_moves``).

The references were made by ``tests/data/te_moves/make_references.py`` on the commit
named in ``origin.txt`` (made again when the control changes, never for speed work): a
change that only makes the loop faster must leave every move as it was. :data:`MOVES_ATOL` is the
tolerance (0: bit for bit); the compiled plant, the core's kernels and NumPy's
elementwise functions give the same bits on x86-64 from run to run.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parent / "data" / "te_moves"
#: Largest allowed difference of a move (% or kPa or degC): round-off only. The
#: same code on another numpy/OpenBLAS build differs in the last bits (measured
#: with numpy 2.4.6, scipy 1.16-1.17: at most 4e-12 in the short cases and 5e-8
#: over the 48 h run), far below any change of the control law.
MOVES_ATOL = 1e-6


def _references():
    spec = importlib.util.spec_from_file_location("te_moves_refs", DATA / "make_references.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


REFS = _references()


def _check(name: str) -> None:
    r = REFS.run_case(name)
    stride = REFS.STRIDE_48H if name.endswith("48h") else 1
    with np.load(DATA / f"{name}.npz") as z:
        want_xmv, want_sp, want_active = z["xmv"], z["setpoints"], z["active"]
    got_xmv, got_sp = r.xmv[::stride], r.setpoints[::stride]
    assert got_xmv.shape == want_xmv.shape
    np.testing.assert_allclose(got_xmv, want_xmv, rtol=0, atol=MOVES_ATOL)
    np.testing.assert_allclose(got_sp, want_sp, rtol=0, atol=MOVES_ATOL)
    np.testing.assert_array_equal(r.active[::stride], want_active)


@pytest.mark.parametrize("name", ["ssmpc_0_2_3", "ssmpc_0_2_noise", "fixed_0_2"])
def test_short_runs_move_as_stored(name):
    _check(name)


@pytest.mark.slow
def test_bench_run_moves_as_stored():
    """The 48 h run of ``ssmpc bench te-closed-loop`` (every 10th sample stored)."""
    _check("ssmpc_bench_48h")
