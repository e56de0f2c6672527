"""``ssmpc plants``: the plants, their variables and operating points with stability types."""

from __future__ import annotations

from plant_sim import plant_names
from services.cli.plant_info import build_plant, describe_plant
from services.output import CLIError, emit_json


def register(sub) -> None:
    p = sub.add_parser("plants", help="list plants and their operating points")
    p.add_argument("--plant", action="append", default=[], metavar="NAME",
                   help="only this plant (repeatable)")
    p.add_argument("--json", action="store_true", help="print a JSON document as the last line")
    p.set_defaults(func=_run)


def _run(args) -> int:
    names = plant_names()
    for n in args.plant:
        if n not in names:
            raise CLIError(f"plant: unknown plant {n!r}; known: {', '.join(names)}")
    selected = args.plant or names
    docs = []
    for name in selected:
        try:
            plant = build_plant(name)
        except (ImportError, AttributeError) as exc:
            # a plant whose module is not installed/built yet: list it, do not fail
            docs.append({"name": name, "available": False, "error": str(exc)})
            continue
        doc = describe_plant(plant)
        doc["available"] = True
        docs.append(doc)
    if not args.json:
        _print_table(docs)
    else:
        emit_json({"plants": docs})
    return 0


def _names(vars_, limit: int = 8):
    if len(vars_) > limit:
        head = ", ".join(f"{v['name']} [{v['unit']}]" for v in vars_[:3])
        return f"{len(vars_)}: {head}, ... {vars_[-1]['name']} [{vars_[-1]['unit']}]"
    return ", ".join(f"{v['name']} [{v['unit']}]" for v in vars_) or "-"


def _print_table(docs) -> None:
    for d in docs:
        if not d.get("available", True):
            print(f"{d['name']}: not available ({d['error']})\n")
            continue
        flag = "  [reconstructed]" if d["reconstructed"] else ""
        print(f"{d['name']}: {d['title']}{flag}")
        print(f"  time unit    {d['time_unit']}")
        print(f"  states       {_names(d['states'])}")
        print(f"  inputs       {_names(d['inputs'])}")
        print(f"  outputs      {_names(d['outputs'])}")
        if d["disturbances"]:
            print(f"  disturbances {_names(d['disturbances'])}")
        for op in d["operating_points"]:
            notes = []
            if not op["valid"]:
                notes.append("not a valid operating point")
            if op["confidence"] == "reconstructed":
                notes.append("reconstructed")
            note = f"  ({'; '.join(notes)})" if notes else ""
            detail = op["stability_detail"] or op["stability"]
            y = ", ".join(f"{o['name']}={v:.6g}" for o, v in zip(d["outputs"], op["y"] or []))
            print(f"  {op['name']:<6} {op['stability']:<9} {detail:<14} {y}{note}")
        print()
