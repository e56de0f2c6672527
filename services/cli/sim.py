"""``ssmpc sim PLANT ...``: open-loop simulation to CSV.

The unit plants are run by :mod:`services.cli.sim_unit`; the Tennessee Eastman plant
by :mod:`services.cli.sim_te` (Euler at the original driver's step, the reference CSV
layout). Both write their output atomically: an error leaves no partial file.
"""

from __future__ import annotations

import importlib


def register(sub) -> None:
    p = sub.add_parser("sim", help="open-loop simulation of a plant to CSV")
    p.add_argument("plant", help="plant name (see `ssmpc plants`)")
    p.add_argument("--out", required=True, help="output CSV path")
    p.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    p.add_argument("--hours", type=float, required=True,
                   help="simulated duration in the plant's time unit (h; s for calcium; "
                        "dimensionless time for the CSTR)")
    # unit plants
    g = p.add_argument_group("unit plants")
    g.add_argument("--op", help="operating point to start from (OPI, OPII, OPIII)")
    g.add_argument("--step", action="append", default=[], metavar="INPUT=VALUE@T",
                   help="step input INPUT to VALUE at time T (repeatable)")
    g.add_argument("--plot", help="also write a PNG figure of the run")
    g.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="plant option, e.g. gamma=inf, sigma=ref94, inputs=flows")
    g.add_argument("--sample", type=float, default=None,
                   help="output sample period (default: duration/500)")
    # Tennessee Eastman
    t = p.add_argument_group("Tennessee Eastman (plant te)")
    t.add_argument("--dt", type=float, default=1.8, help="Euler step in seconds (default 1.8)")
    t.add_argument("--noise", choices=["on", "off"], default="off", help="measurement noise")
    t.add_argument("--seed", type=float, default=None,
                   help="random generator seed (default: the original 1431655765)")
    t.add_argument("--idv", action="append", default=[], metavar="K@T_H",
                   help="switch disturbance IDV(K) on at T_H hours (repeatable)")
    t.add_argument("--mode", default="base", help="start mode: base or 1..6 (Ricker 1995)")
    t.add_argument("--literals", choices=["single", "double"], default="single",
                   help="numeric literals as the published build (single) or all double")
    t.add_argument("--record-every", type=float, default=0.01, help="CSV row period in hours")
    p.set_defaults(func=_run)


def _run(args) -> int:
    module = "services.cli.sim_te" if args.plant == "te" else "services.cli.sim_unit"
    return importlib.import_module(module).run(args)
