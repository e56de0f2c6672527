"""Write the stored TE closed-loop moves of ``tests/test_te_moves_reference.py``.

Run from the repository root on the commit the references are to pin::

    python tests/data/te_moves/make_references.py

One ``.npz`` per case of :data:`CASES` (``xmv``: the 12 XMVs in force after each
sample's decision, (K, 12), %; ``setpoints``: the five inner-loop set points, (K, 5);
``active``: the active model, (K,)), and ``origin.txt`` with the commit they came from.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))

from controller.units.te.control import plant_seed_for, run_te  # noqa: E402
from controller.units.te.grades import Leg, TransitionPlan  # noqa: E402

#: name -> (strategy, plan legs, hours, noise, plant noise seed or None); the 48 h
#: case is ``ssmpc bench te-closed-loop``'s run, stored every STRIDE_48H-th sample
CASES = {
    "ssmpc_bench_48h": ("ssmpc", (Leg(1.0, "mode2"), Leg(25.0, "mode3")), 48.0, False, None),
    "ssmpc_0_2_3": ("ssmpc", (Leg(0.5, "mode2"), Leg(2.0, "mode3")), 3.0, False, None),
    "ssmpc_0_2_noise": ("ssmpc", (Leg(0.5, "mode2"),), 3.0, True, 1),
    "fixed_0_2": ("fixed", (Leg(0.5, "mode2"),), 2.0, False, None),
}

STRIDE_48H = 10


def run_case(name: str):
    strategy, legs, hours, noise, seed = CASES[name]
    plan = TransitionPlan("mode0", legs)
    return run_te(strategy, plan, hours, noise=noise, stop_on_trip=False,
                  plant_seed=None if seed is None else plant_seed_for(seed))


def main() -> None:
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=HERE).stdout.strip()
    for name in CASES:
        r = run_case(name)
        rows = slice(None, None, STRIDE_48H if name.endswith("48h") else 1)
        np.savez_compressed(HERE / f"{name}.npz", xmv=r.xmv[rows],
                            setpoints=r.setpoints[rows], active=r.active[rows])
    (HERE / "origin.txt").write_text(
        f"Produced by tests/data/te_moves/make_references.py at commit {commit}\n"
        f"numpy {np.__version__}, Python {sys.version.split()[0]}, x86-64 Linux.\n")


if __name__ == "__main__":
    main()
