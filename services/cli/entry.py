"""``ssmpc`` command line.

Subcommands live in :mod:`services.cli` (one module may register several);
benchmarks in :mod:`services.bench`; seed results in :mod:`services.reproduce`.
Errors go to stderr as ``error: ...`` with exit code 2; JSON output is one object
on the last stdout line.
"""

from __future__ import annotations

import os

# Small dense matrices in a real-time loop: BLAS threads only add jitter and, on a
# loaded 2-core machine, made an H-infinity synthesis 20x slower. Set before numpy loads.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import pkgutil  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from services.output import CLIError, emit_json  # noqa: E402

__all__ = ["main", "build_parser", "COMMAND_MODULES"]

#: Modules that register ``ssmpc`` subcommands (``register(subparsers)``).
COMMAND_MODULES = (
    "services.cli.campaign",
    "services.cli.credentials",
    "services.cli.kpis",
    "services.cli.linearize",
    "services.nodes.run",
    "services.cli.operator",
    "services.cli.plants",
    "services.cli.router",
    "services.cli.sim",
    "services.cli.soak",
    "services.nodes.supervisor",
)


BENCH_HELP = "run a benchmark (median, p99, max, machine)"


def _add_bench(sub) -> None:
    import services.bench as pkg

    p = sub.add_parser("bench", help=BENCH_HELP)
    bsub = p.add_subparsers(dest="bench_name", metavar="NAME", required=True)
    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"services.bench.{info.name}")
        bp = bsub.add_parser(mod.NAME, help=getattr(mod, "DESCRIPTION", ""))
        bp.add_argument("--json", action="store_true", help="print the JSON document")
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(bp)
        bp.set_defaults(func=_run_bench, bench_module=mod)


def _run_bench(args) -> int:
    from services.bench._common import bench_document
    from services.machine import load_average

    mod = args.bench_module
    before = load_average()
    cases = mod.run(args)
    doc = bench_document(mod.NAME, cases, load={"before": before, "after": load_average()})
    if not args.json:
        print(f"bench {doc['bench']} on {doc['machine']}")
        for c in doc["cases"]:
            print(f"  {c['case']:<24} median {c['median']:.4g} {c['unit']}  "
                  f"p99 {c['p99']:.4g}  max {c['max']:.4g}  n={c['n']}")
    emit_json(doc)
    return 0


def _add_reproduce(sub) -> None:
    p = sub.add_parser("reproduce", help="reproduce seed results (ids of seed_results.md)")
    p.add_argument("id", nargs="+",
                   help="result ids, e.g. R3.2 or R7.13 R7.14 R7.16 (run in the order given); "
                        "'list' lists the available ids")
    p.add_argument("--json", action="store_true", help="print the JSON record")
    p.add_argument("--plot", metavar="DIR", help="write figures into DIR")
    p.add_argument("--seed", type=int, default=0, help="random seed for studies that draw")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes for a study's independent closed-loop runs (TE studies; "
                        "the numbers do not depend on it; default 1)")
    p.set_defaults(func=_run_reproduce)


def _run_reproduce(args) -> int:
    """One or more seed results; the last line is the result's JSON record (one id) or
    ``{"results": [record, ...]}`` in the order given (several ids)."""
    from services.reproduce import StudyContext, discover_studies

    studies = discover_studies()
    ids = list(args.id)
    if "list" in ids:
        if len(ids) > 1:
            raise CLIError("id: 'list' stands alone (got also "
                           f"{', '.join(i for i in ids if i != 'list')})")
        from services.reproduce.titles import TITLES, last_verdicts

        seen = last_verdicts()
        rows = [{"id": rid, "title": TITLES.get(rid, ""),
                 "verdict": seen.get(rid, {}).get("verdict")}
                for rid in sorted(studies, key=_id_key)]
        if args.json:
            emit_json({"results": rows})
        else:
            print(f"{'id':<7} {'last verdict':<13} what it compares")
            for r in rows:
                print(f"{r['id']:<7} {r['verdict'] or '-':<13} {r['title']}")
        return 0
    # every id checked before any study runs: a typo in the third does not cost the first two
    rids = [i.upper() for i in ids]
    unknown = [i for i, rid in zip(ids, rids, strict=True) if rid not in studies]
    if unknown:
        raise CLIError(f"id: unknown or not yet reproducible result "
                       f"{', '.join(repr(i) for i in unknown)}; "
                       f"available: {', '.join(sorted(studies, key=_id_key)) or 'none'}")
    rids = list(dict.fromkeys(rids))  # each once, in the order given
    plot_dir = None
    if args.plot:
        plot_dir = Path(args.plot)
        try:
            plot_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CLIError(f"plot: cannot create {args.plot!r}: {exc}") from exc
    try:
        ctx = StudyContext(plot_dir=plot_dir, seed=args.seed, workers=args.workers)
    except ValueError as exc:
        raise CLIError(str(exc)) from exc
    from services.reproduce.titles import record_verdict

    docs = []
    for rid in rids:
        doc = studies[rid](ctx).as_dict()
        record_verdict(rid, doc["verdict"])
        docs.append(doc)
        if not args.json:
            print(f"{doc['id']}: {doc['verdict']} - {doc['why']}")
            for r in doc["rows"]:
                print(f"  {r['name']:<40} seed {r['seed']!s:>12}  ours {r['ours']:.6g} "
                      f"{r['unit']}")
    emit_json(docs[0] if len(docs) == 1 else {"results": docs})
    return 0


def _id_key(rid: str):
    try:
        chap, num = rid[1:].split(".")
        return (int(chap), int(num))
    except ValueError:
        return (99, 0)


def _command(argv: list[str]) -> str | None:
    """The subcommand ``argv`` names (its first word that is not an option), or None."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``ssmpc`` parser; given the ``argv`` it will parse, the benchmarks' own
    parsers are built only for ``ssmpc bench``.

    Building them imports every benchmark and, through them, the controller's numerical
    core (numba, scipy): about 1 s of every command's start on a 2-vCPU AMD EPYC, and of
    every node's start and restart under ``ssmpc up``. Without ``argv`` the whole
    parser is built.
    """
    parser = argparse.ArgumentParser(
        prog="ssmpc",
        description="State-shared multiple-model transition controller for process plants.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    if argv is None or _command(argv) == "bench":
        _add_bench(sub)
    else:  # listed in ``ssmpc --help``; a command of its own never reaches it
        sub.add_parser("bench", help=BENCH_HELP)
    _add_reproduce(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
    except CLIError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.code
    except ValueError as exc:  # PlantInputError, settings validation, ...
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # a defect: say so in one line, keep the traceback for a log
        import logging

        logging.getLogger("ssmpc").debug("unhandled error", exc_info=exc)
        print(f"error: internal error ({type(exc).__name__}: {exc}); run with "
              f"SSMPC_DEBUG=1 for the traceback", file=sys.stderr)
        if os.environ.get("SSMPC_DEBUG"):
            import traceback

            traceback.print_exc()
        return 1
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
