"""``ssmpc campaign SPEC.json [--out DIR] [--scheduler ADDR] [--workers N] [--json]``.

Many offline closed-loop runs on Dask (:mod:`services.campaign`). The spec is
validated whole before anything runs or is written (``error: <field>: ...``, exit
2). Progress goes to stderr; with ``--json`` the campaign document is the last
stdout line. Exit 0 when every run finished (tripped or not), 1 when some run
failed (its row carries the error; the other runs are kept), 130 on Ctrl-C (the
finished runs are kept in ``--out`` and skipped by the next start).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from services.output import CLIError, emit_json

__all__ = ["register"]


def register(sub) -> None:
    p = sub.add_parser("campaign", help="many offline closed-loop runs on Dask (a spec file)")
    p.add_argument("spec", help="campaign spec, JSON (see docs/campaigns.md)")
    p.add_argument("--out", metavar="DIR",
                   help="results directory (results.json, runs/, report); an existing one "
                        "is resumed: its finished runs are not run again")
    p.add_argument("--scheduler", metavar="ADDR",
                   help="a running Dask scheduler, e.g. tcp://HOST:8786 (default: a local "
                        "cluster of worker processes)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local cluster: worker processes (default: the cores); with "
                        "--scheduler: wait for N workers")
    p.add_argument("--json", action="store_true", help="print the campaign document")
    p.set_defaults(func=_run)


def load_spec(path: str):
    """Read and validate a spec file; every problem is a CLIError naming the field."""
    from services.campaign.spec import SpecError, parse_spec

    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise CLIError(f"spec: cannot read {path!r}: {exc.strerror or exc}") from None
    try:
        data = json.loads(text, parse_constant=_reject_constant)
    except (json.JSONDecodeError, ValueError) as exc:
        raise CLIError(f"spec: {path!r} is not valid JSON: {exc}") from None
    try:
        return parse_spec(data, default_name=Path(path).stem)
    except SpecError as exc:
        raise CLIError(str(exc)) from None


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a number")


def _check_out(out: str | None) -> None:
    if out is None:
        return
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise CLIError(f"out: {out!r} exists and is not a directory")
    parent = p.parent if p.parent != Path("") else Path(".")
    if not p.exists() and not parent.exists():
        raise CLIError(f"out: parent directory {str(parent)!r} does not exist")


def _run(args) -> int:
    from services.campaign.driver import run_campaign

    spec = load_spec(args.spec)
    if args.workers is not None and args.workers < 1:
        raise CLIError(f"workers: need at least 1, got {args.workers}")
    _check_out(args.out)
    try:
        doc = run_campaign(spec, args.out, scheduler=args.scheduler, workers=args.workers)
    except ConnectionError as exc:
        raise CLIError(str(exc)) from None
    except OSError as exc:  # the results directory cannot be written (full, read-only)
        raise CLIError(f"out: cannot write the results: {exc}", code=1) from None
    except KeyboardInterrupt:
        if args.out:
            kept = len(list((Path(args.out) / "runs").glob("*.npz")))
            print(f"\ninterrupted: {kept} finished runs kept in {args.out}; the same command "
                  f"goes on from there", file=sys.stderr)
        return 130
    if not args.json:
        s = doc["summary"]
        print(f"campaign {doc['campaign']}: {s['runs']} runs ({s['executed']} run now, "
              f"{s['skipped']} found finished), {s['tripped']} tripped, {s['errors']} failed, "
              f"{doc['workers']} workers, {doc['wall_s']:.1f} s")
        if args.out:
            print(f"results: {Path(args.out) / 'results.json'}; report: "
                  f"{Path(args.out) / 'report.html'}")
    else:
        emit_json(doc)
    return 1 if doc["summary"]["errors"] else 0
