"""The campaign report: matrix figure (PNG), a table (CSV) and a small HTML page.

:func:`write_report` writes ``report.png`` (:func:`services.campaign.figures.plot_matrix`),
``table.csv`` (one row per run, the columns of :data:`COLUMNS`) and ``report.html``
(the figure, the summary, the acceptance verdicts and the same table; no script, no
external resource), each atomically. A TE campaign with the product strategy
``ssmpc`` and at least one baseline also gets ``acceptance.json`` and
``acceptance.md`` (:mod:`services.campaign.acceptance`).
"""

from __future__ import annotations

import csv
import html
import io
import json
from pathlib import Path

from services.output import atomic_output

__all__ = ["COLUMNS", "table_rows", "write_report"]

#: (header, row key or callable) of the table.
COLUMNS = (
    ("case", "case"), ("strategy", "strategy"), ("seed", "seed"), ("hours", "hours"),
    ("tripped", "tripped"),
    ("trip at, h", lambda r: (r.get("trip") or {}).get("at_h")),
    ("trip reason", lambda r: (r.get("trip") or {}).get("reason")),
    ("time to grade, h", "time_to_grade_h"), ("peak pressure, kPa", "peak_pressure_kpa"),
    ("mean cost, $/h", "mean_cost_usd_h"), ("final cost, $/h", "final_cost_usd_h"),
    ("transition cost, $", "transition_cost_usd"),
    ("G std, mol %", lambda r: (r.get("product_variability") or {}).get("g_std_mol")),
    ("production std, %",
     lambda r: (r.get("product_variability") or {}).get("production_std_pct")),
    ("active models", lambda r: " ".join(f"{k} {v:.2f}" for k, v in
                                         (r.get("active_model_share") or {}).items())),
    ("limit bound, share", "limit_bound_share"), ("binding limit", "binding_limit"),
    ("wall, s", "wall_s"), ("error", "error"), ("run", "run"),
)


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def table_rows(doc: dict) -> list[list[str]]:
    """The table's text cells, one list per run (header first)."""
    out = [[h for h, _ in COLUMNS]]
    for r in doc["runs"]:
        out.append([_cell(key(r) if callable(key) else r.get(key)) for _, key in COLUMNS])
    return out


def write_report(doc: dict, root: str | Path) -> dict[str, str]:
    """Write the report files into ``root``; returns their paths by kind."""
    from services.campaign.figures import plot_matrix

    root = Path(root)
    png = plot_matrix(doc, root / "report.png")
    rows = table_rows(doc)
    buf = io.StringIO()
    csv.writer(buf).writerows(rows)
    with atomic_output(root / "table.csv", "w", field="out") as fh:
        fh.write(buf.getvalue())
    paths = {"png": png, "csv": str(root / "table.csv"), "html": str(root / "report.html")}
    verdicts = ""
    strategies = {r.get("strategy") for r in doc.get("runs", [])}
    if doc.get("unit", "te") == "te" and "ssmpc" in strategies and len(strategies) > 1:
        from services.campaign.acceptance import judge, to_markdown

        acc = judge(doc)
        text = to_markdown(acc)
        with atomic_output(root / "acceptance.json", "w", field="out") as fh:
            json.dump(acc.as_dict(), fh, indent=1)
        with atomic_output(root / "acceptance.md", "w", field="out") as fh:
            fh.write(text)
        paths.update(acceptance_json=str(root / "acceptance.json"),
                     acceptance_md=str(root / "acceptance.md"))
        verdicts = (f"<h2>acceptance of ssmpc: {'met' if acc.met else 'not met'}</h2>\n"
                    f"<pre>{html.escape(text)}</pre>")
    s = doc["summary"]
    head = "".join(f"<th>{html.escape(h)}</th>" for h in rows[0])
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                     for r in rows[1:])
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>campaign {html.escape(str(doc['campaign']))}</title>
<style>body{{font-family:sans-serif;margin:1.5em}}table{{border-collapse:collapse;font-size:90%}}
td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}th{{background:#eee}}</style>
</head><body>
<h1>campaign {html.escape(str(doc['campaign']))}</h1>
<p>unit {html.escape(str(doc.get('unit', '')))}: {s['runs']} runs, {s['tripped']} tripped,
{s.get('errors', 0)} failed; {doc['workers']} workers, {doc['wall_s']:.1f} s wall
({s.get('executed', 0)} run now, {s.get('skipped', 0)} found finished).</p>
<p><img src="report.png" alt="cases x strategies: time to grade or trip"></p>
{verdicts}
<table><thead><tr>{head}</tr></thead><tbody>
{body}
</tbody></table>
</body></html>
"""
    with atomic_output(root / "report.html", "w", field="out") as fh:
        fh.write(page)
    return paths
