"""``ssmpc soak``: a long closed-loop run with random transitions, IDVs and injected faults.

Writes the soak report (docs/soak.md) (``--report F``, atomically) and prints it as the
last stdout line. The fault grammar is in :mod:`services.soak.faults`; the layout and
the counting rules in :mod:`services.soak.run`.
"""

from __future__ import annotations

import json

from services.output import CLIError, atomic_output, check_writable, emit_json

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser("soak", help="long closed-loop run with random transitions, "
                                    "disturbances and injected faults")
    p.add_argument("--unit", default="te", help="unit (default te)")
    p.add_argument("--hours", type=float, required=True, help="process hours to run")
    p.add_argument("--speed", type=float, default=3600.0,
                   help="process seconds per wall second (default 3600)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    p.add_argument("--faults", default=None, metavar="SPEC",
                   help="fault schedule, e.g. 'kill:controller@0.5h,drop:meas:5%%@1h-1.2h' "
                        "(default: every kind once; 'none': no faults)")
    p.add_argument("--transition-gap-h", type=float, default=2.0,
                   help="mean process hours between transitions (default 2)")
    p.add_argument("--idv-gap-h", type=float, default=6.0,
                   help="mean process hours between disturbances (default 6)")
    p.add_argument("--grades", default=None, metavar="LIST",
                   help="grades to move between, e.g. mode0,mode2 (default: the unit's)")
    p.add_argument("--idvs", default=None, metavar="LIST",
                   help="IDVs to switch at random, e.g. 1,2,5 (default: all but IDV7)")
    p.add_argument("--unpreventable-idvs", default="", metavar="LIST",
                   help="a trip while one of these IDVs is on is not counted as preventable")
    p.add_argument("--no-noise", action="store_true", help="TE measurement noise off")
    p.add_argument("--unit-config", metavar="FILE",
                   help="JSON overrides of the unit config, e.g. {\"strategy\": \"pi\"}")
    p.add_argument("--state-dir", default=None,
                   help="keep the store and node logs here (default: a temporary directory)")
    p.add_argument("--report", required=True, metavar="FILE", help="report JSON file")
    p.set_defaults(func=run)


def run(args) -> int:
    from services.registry import load_unit_config
    from services.soak.faults import FaultSpecError, parse_faults
    from services.soak.run import SoakSettings, run_soak

    check_writable(args.report, "report")

    def idv_list(text, name):
        try:
            out = tuple(int(x) for x in text.split(",") if x.strip())
        except ValueError as exc:
            raise CLIError(f"{name}: expected IDV numbers like 1,2,5, got {text!r}") from exc
        if any(not 1 <= k <= 20 for k in out):
            raise CLIError(f"{name}: IDV numbers are 1..20, got {text!r}")
        return out

    idvs = () if args.idvs is None else idv_list(args.idvs, "idvs")
    unpreventable = idv_list(args.unpreventable_idvs, "unpreventable_idvs")
    overrides = {}
    if args.unit_config:
        try:
            overrides = json.loads(open(args.unit_config).read())
        except (OSError, ValueError) as exc:
            raise CLIError(f"unit_config: cannot read {args.unit_config!r}: {exc}") from exc
        if not isinstance(overrides, dict):
            raise CLIError("unit_config: expected a JSON object")
    try:
        cfg = load_unit_config(args.unit, args.unit_config)
        faults = (None if args.faults is None
                  else tuple(parse_faults(args.faults, cfg.sample_period_s)))
        settings = SoakSettings(unit=args.unit, hours=args.hours, speed=args.speed,
                                seed=args.seed, faults=faults,
                                transition_gap_h=args.transition_gap_h,
                                idv_gap_h=args.idv_gap_h, noise=not args.no_noise,
                                idvs=idvs, unpreventable_idvs=unpreventable,
                                unit_config=overrides,
                                grades=tuple(g.strip() for g in (args.grades or "").split(",")
                                             if g.strip()),
                                state_dir=args.state_dir)
    except (FaultSpecError, ValueError) as exc:
        raise CLIError(str(exc)) from exc
    report = run_soak(settings)
    with atomic_output(args.report, field="report") as fh:
        fh.write(json.dumps(report, indent=1, allow_nan=False) + "\n")
    emit_json(report)
    return 0 if report["records_lost"] == 0 and report["unhandled_errors"] == 0 else 1
