"""Test-session setup shared by every test module."""

import os

# As in the CLI: single-threaded BLAS for small matrices (set before numpy loads).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")
