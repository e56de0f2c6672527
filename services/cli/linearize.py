"""``ssmpc linearize PLANT --op OP``: A, B, C, D at an operating point."""

from __future__ import annotations

import numpy as np

from plant_sim.linearize import linearize
from services.cli.plant_info import build_plant, parse_options
from services.output import emit_json


def register(sub) -> None:
    p = sub.add_parser("linearize", help="linear model (A, B, C, D) at an operating point")
    p.add_argument("plant", help="plant name (see `ssmpc plants`)")
    p.add_argument("--op", required=True, help="operating point (OPI, OPII, OPIII)")
    p.add_argument("--inputs", help="comma-separated input names to keep (default all)")
    p.add_argument("--outputs", help="comma-separated output names to keep (default all)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="plant option, e.g. gamma=inf (cstr) or sigma=ref94 (bioreactor)")
    p.add_argument("--json", action="store_true", help="print the JSON object as the last line")
    p.set_defaults(func=_run)


def _split(text):
    return None if text is None else [s.strip() for s in text.split(",") if s.strip()]


def _run(args) -> int:
    plant = build_plant(args.plant, parse_options(args.option))
    op = plant.operating_point(args.op)
    lm = linearize(plant, op).select(inputs=_split(args.inputs), outputs=_split(args.outputs))
    doc = lm.as_dict()
    if lm.B.shape[1] == 1 and lm.C.shape[0] == 1:
        num, den = lm.to_transfer_function()
        doc["transfer_function"] = {"num": num.tolist(), "den": den.tolist()}
    if args.json:
        emit_json(doc)
        return 0
    with np.printoptions(precision=6, suppress=False, linewidth=120):
        print(f"{plant.name} at {op.name} ({op.stability_detail or op.stability}); "
              f"time unit {plant.time_unit}")
        print(f"states  {', '.join(lm.state_names)}")
        print(f"inputs  {', '.join(lm.input_names)}")
        print(f"outputs {', '.join(lm.output_names)}")
        for name in ("A", "B", "C", "D"):
            print(f"{name} =\n{getattr(lm, name)}")
        print(f"eigenvalues {lm.eigenvalues()}  -> {' / '.join(lm.stability())}")
        if "transfer_function" in doc:
            print(f"G(s) num {np.array(doc['transfer_function']['num'])} "
                  f"den {np.array(doc['transfer_function']['den'])}")
    return 0
