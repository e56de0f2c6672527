"""``ssmpc transition UNIT GRADE``, ``ssmpc status UNIT``, ``ssmpc disturbance UNIT NAME VALUE``:
a thin REST client for operators.

Talks to an api node (``--api``, default http://127.0.0.1:8000; the token from
``--token`` or ``SSMPC_API_TOKEN``). Readable text by default, ``--json`` for
scripts (one object on the last stdout line).
"""

from __future__ import annotations

import os
import time

from services.output import CLIError, emit_json

__all__ = ["register"]


def _common(p) -> None:
    p.add_argument("--api", default="http://127.0.0.1:8000", help="api node URL")
    p.add_argument("--token", default=None, help="bearer token (default $SSMPC_API_TOKEN)")
    p.add_argument("--timeout", type=float, default=10.0, help="HTTP timeout, s")
    p.add_argument("--json", action="store_true", help="print the JSON document")


def register(sub) -> None:
    p = sub.add_parser("transition", help="request a grade transition through the REST API")
    p.add_argument("unit")
    p.add_argument("grade")
    p.add_argument("--duration-h", type=float, default=None, help="transition duration, h")
    p.add_argument("--wait", action="store_true", help="poll until the transition ends")
    p.add_argument("--wait-timeout", type=float, default=600.0, help="longest wait, wall s")
    _common(p)
    p.set_defaults(func=run_transition)

    p = sub.add_parser("disturbance",
                       help="switch a plant disturbance through the REST API (TE: IDVk 1|0)")
    p.add_argument("unit")
    p.add_argument("name", help="IDV1..IDV20 for TE, or a disturbance variable of a unit plant")
    p.add_argument("value", type=float, help="new value (TE IDVs: 1 on, 0 off)")
    _common(p)
    p.set_defaults(func=run_disturbance)

    p = sub.add_parser("status", help="show a unit's status through the REST API")
    p.add_argument("unit")
    p.add_argument("--all", action="store_true", help="list every CV")
    _common(p)
    p.set_defaults(func=run_status)


def _client(args):
    import httpx

    token = args.token or os.environ.get("SSMPC_API_TOKEN") or None
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return httpx.Client(base_url=args.api, headers=headers, timeout=args.timeout)


def _check(resp) -> dict:
    if resp.status_code >= 400:
        try:
            detail = resp.json().get("detail")
        except ValueError:
            detail = resp.text
        raise CLIError(f"api: HTTP {resp.status_code}: {detail}")
    return resp.json()


def _get(client, path):
    import httpx

    try:
        return _check(client.get(path))
    except httpx.HTTPError as exc:
        raise CLIError(f"api: cannot reach {client.base_url}: {exc}") from exc


def run_transition(args) -> int:
    import httpx

    body = {"grade": args.grade}
    if args.duration_h is not None:
        body["duration_h"] = args.duration_h
    with _client(args) as c:
        try:
            view = _check(c.post(f"/api/v1/units/{args.unit}/transitions", json=body))
        except httpx.HTTPError as exc:
            raise CLIError(f"api: cannot reach {args.api}: {exc}") from exc
        if not args.json:
            print(f"transition {view['id']}: {view.get('from_grade')} -> {view['grade']} "
                  f"{view['state']}")
        if args.wait:
            t_end = time.monotonic() + args.wait_timeout
            while view["state"] in ("pending", "running") and time.monotonic() < t_end:
                time.sleep(0.5)
                view = _get(c, f"/api/v1/units/{args.unit}/transitions/{view['id']}")
                if not args.json:
                    eta = view.get("eta_s")
                    print(f"  {view['state']:<8} progress {100 * view['progress']:5.1f} %  "
                          f"ISE {view['ise']:.4g}  ETA "
                          f"{'-' if eta is None else f'{eta / 3600:.2f} h'}", flush=True)
    if args.json:
        emit_json(view)
    return 0 if view["state"] not in ("failed",) else 1


def run_disturbance(args) -> int:
    import httpx

    with _client(args) as c:
        try:
            out = _check(c.post(f"/api/v1/units/{args.unit}/disturbances",
                                json={"name": args.name, "value": args.value}))
        except httpx.HTTPError as exc:
            raise CLIError(f"api: cannot reach {args.api}: {exc}") from exc
    if args.json:
        emit_json(out)
    else:
        on = {k: v for k, v in out["disturbances"].items() if v}
        print(f"{args.unit}: {args.name} = {args.value:g}; active: "
              + (", ".join(f"{k}={v:g}" for k, v in on.items()) or "none"))
    return 0


def run_status(args) -> int:
    with _client(args) as c:
        st = _get(c, f"/api/v1/units/{args.unit}/status")
    if args.json:
        emit_json(st)
        return 0
    print(f"unit {st['unit']} ({st['plant']})  sample {st['sample']}  "
          f"t = {st['process_time_s'] / 3600:.3f} h  grade {st['grade']}")
    print("  CV        value        reference")
    tracked = [n for n in st["cv"] if n in st["ref"]]
    shown = list(st["cv"]) if args.all or len(st["cv"]) <= 8 else tracked
    for name in shown:
        v, r = st["cv"][name], st["ref"].get(name)
        print(f"  {name:<8} {'-' if v is None else f'{v:12.5g}'}  "
              f"{'-' if r is None else f'{r:12.5g}'}")
    if len(shown) < len(st["cv"]):
        print(f"  ({len(st['cv']) - len(shown)} more CVs: --all)")
    print("  MV: " + ", ".join(f"{k}={v:.5g}" for k, v in st["mv"].items() if v is not None))
    print(f"  active model {st['active_model_name']}  J "
          + ", ".join(f"{k}={v:.3g}" for k, v in st["J"].items() if v is not None))
    solve = st["solve_ms"]
    print(f"  solve {'-' if solve is None else f'{solve:.3f} ms'} (budget {st['budget_ms']:.3g} ms)"
          f"  deadline misses {st['deadline_misses']}  fallback moves {st['fallback_moves']}")
    tr = st.get("transition")
    if tr:
        print(f"  transition {tr['id']} -> {tr['grade']}: {tr['state']}, "
              f"progress {100 * tr['progress']:.1f} %, ISE {tr['ise']:.4g}")
    for a in st.get("alarms", [])[-5:]:
        print(f"  alarm: {a}")
    return 0
