"""``ssmpc kpis UNIT [--json]``: a unit's KPIs through the REST API, as an APC engineer
reads them (service factor, constraint activity, cost against the base case,
prediction error per model; ``GET /api/v1/units/{unit}/kpis``).

The text view fits :data:`~services.cli.operator.STATUS_WIDTH` columns: one line per
window (since start, 1 h, 24 h) with the service factor, how the time split and the
mean cost against the base case; the variables that sat at a limit, most active first
(``--all``: every counted variable); each model's mean RMS prediction error.
"""

from __future__ import annotations

from urllib.parse import quote

from services.cli.operator import STATUS_WIDTH, _client, _common, _get
from services.output import emit_json

__all__ = ["register", "kpi_lines"]

#: Variables listed without ``--all``.
TOP_VARIABLES = 12


def register(sub) -> None:
    p = sub.add_parser("kpis", help="a unit's KPIs through the REST API: service factor, "
                                    "constraint activity, cost vs base case, prediction "
                                    "error per model")
    p.add_argument("unit")
    p.add_argument("--all", action="store_true",
                   help="list every counted CV and MV, also those never at a limit")
    _common(p)
    p.set_defaults(func=run_kpis)


def _pct(v, width: int) -> str:
    return f"{'-':>{width}}" if v is None else f"{100.0 * v:>{width}.1f}"


def _num(v, width: int, fmt: str = ".1f", sign: str = "") -> str:
    return f"{'-':>{width}}" if v is None else f"{v:>{sign}{width}{fmt}}"


def kpi_lines(doc: dict, show_all: bool = False) -> list[str]:
    """The text view of a KPI document (each line at most ``STATUS_WIDTH`` columns)."""
    windows = doc.get("windows") or []
    t = doc.get("process_time_s")
    out = [f"{doc['unit']}  sample {doc['sample']}  samples counted {doc['samples']}  "
           f"t {'-' if t is None else f'{t / 3600:.3f} h'}"]
    base = doc.get("base_cost_usd_h")
    if base is not None:
        out.append(f"base case {base:.1f} $/h: {doc.get('base_cost_origin') or '-'}"
                   [:STATUS_WIDTH])
        now = doc.get("cost_now_usd_h")
        out.append(f"cost now {_num(now, 0).strip()} $/h")
    out.append(f"{'':<12} {'':>8} {'service':>8}  {'time, % ON / fallback / WARM / OFF / down':<42}"
               f"{'cost':>9} {'vs base':>8}")
    out.append(f"{'window':<12} {'hours':>8} {'factor %':>8}  {'on':>6} {'fallback':>8} "
               f"{'warm':>6} {'off':>6} {'down':>6}   {'$/h':>9} {'$/h':>8}")
    for w in windows:
        sh, cost = w["time_share"], w["cost"]
        out.append(f"{w['window'][:12]:<12} {w['hours']:>8.3f} {_pct(w['service_factor'], 8)}  "
                   f"{_pct(sh['on'], 6)} {_pct(sh['fallback'], 8)} {_pct(sh['warm'], 6)} "
                   f"{_pct(sh['off'], 6)} {_pct(sh['down'], 6)}   "
                   f"{_num(cost['mean_usd_h'], 9)} {_num(cost['vs_base_usd_h'], 8, sign='+')}")
    if windows:
        out.extend(_activity_lines(windows, show_all))
        out.extend(_model_lines(doc, windows))
    return [ln[:STATUS_WIDTH] for ln in out]


def _activity_lines(windows: list[dict], show_all: bool) -> list[str]:
    rows = {}
    for j, w in enumerate(windows):
        for a in w["constraint_activity"]:
            rows.setdefault(a["name"], {"a": a, "by": [None] * len(windows)})["by"][j] = a
    names = list(rows)
    if not show_all:
        names = [n for n in names if any((a or {}).get("active") for a in rows[n]["by"])]
    first = windows[0]["constraint_activity"]
    order = {a["name"]: -(a.get("active") or 0.0) for a in first}
    names.sort(key=lambda n: order.get(n, 0.0))
    heads = " ".join(f"{w['window'][:11]:>11}" for w in windows)
    out = ["constraint activity, % of samples ON at a limit (lo/hi)",
           f"{'variable':<14} {'description':<26} {heads}"]
    if not names:
        out.append("  none at a limit")
    shown = names if show_all else names[:TOP_VARIABLES]
    for n in shown:
        a = rows[n]["a"]
        cells = []
        for b in rows[n]["by"]:
            if b is None or b.get("at_lo") is None:
                cells.append(f"{'-':>11}")
            else:
                cells.append(f"{100 * b['at_lo']:>5.1f}/{100 * b['at_hi']:<5.1f}")
        out.append(f"{n[:14]:<14} {a.get('description', '')[:26]:<26} {' '.join(cells)}")
    if len(names) > len(shown):
        out.append(f"({len(names) - len(shown)} more at a limit: --all)")
    return out


def _model_lines(doc: dict, windows: list[dict]) -> list[str]:
    models = list(windows[0].get("prediction_rms") or {})
    if not models:
        return []
    now = doc.get("prediction_rms_now") or {}
    heads = " ".join(f"{w['window'][:11]:>11}" for w in windows)
    out = ["prediction error per model (RMS, units of the CVs' scales)",
           f"{'model':<24} {'now':>8} {heads}"]
    for m in models:
        cells = " ".join(_num((w.get("prediction_rms") or {}).get(m), 11, ".3g")
                         for w in windows)
        out.append(f"{m[:24]:<24} {_num(now.get(m), 8, '.3g')} {cells}")
    return out


def run_kpis(args) -> int:
    with _client(args) as c:
        doc = _get(c, f"/api/v1/units/{quote(args.unit, safe='')}/kpis")
    if args.json:
        emit_json(doc)
        return 0
    for line in kpi_lines(doc, args.all):
        print(line)
    return 0
