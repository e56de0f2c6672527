"""``ssmpc transition UNIT GRADE``, ``ssmpc abort UNIT [ID]``, ``ssmpc status UNIT``,
``ssmpc disturbance UNIT NAME VALUE``, ``ssmpc mode UNIT off|warm|on``,
``ssmpc variable UNIT NAME [--mode M] [--value X] [--lo X] [--hi X] [--ramp-per-h X]``,
``ssmpc events UNIT [--since ISO] [--follow]``:
a thin REST client for operators.

Talks to an api node (``--api``, default http://127.0.0.1:8000; the token from
``--token`` or ``SSMPC_API_TOKEN``). Readable text by default, ``--json`` for
scripts (one object on the last stdout line).
"""

from __future__ import annotations

import json
import math
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
    p.add_argument("--queue", action="store_true",
                   help="if a transition is under way, queue this one after it (else 409)")
    p.add_argument("--wait", action="store_true", help="poll until the transition ends")
    p.add_argument("--wait-timeout", type=float, default=600.0, help="longest wait, wall s")
    _common(p)
    p.set_defaults(func=run_transition)

    p = sub.add_parser("abort", help="abort a unit's transition (the running one by default): "
                                     "the set points are held where they are, control goes on")
    p.add_argument("unit")
    p.add_argument("id", nargs="?", default=None, help="transition id (default: the running one)")
    _common(p)
    p.set_defaults(func=run_abort)

    p = sub.add_parser("disturbance",
                       help="switch a plant disturbance through the REST API (TE: IDVk 1|0)")
    p.add_argument("unit")
    p.add_argument("name", help="IDV1..IDV20 for TE, or a disturbance variable of a unit plant")
    p.add_argument("value", type=float, help="new value (TE IDVs: 1 on, 0 off)")
    _common(p)
    p.set_defaults(func=run_disturbance)

    p = sub.add_parser("mode", help="set the controller mode: off (nothing computed or "
                                    "written), warm (computed, not written), on")
    p.add_argument("unit")
    p.add_argument("mode", choices=("off", "warm", "on"))
    _common(p)
    p.set_defaults(func=run_mode)

    p = sub.add_parser("variable", help="operator action on one CV or MV: its mode, held "
                                        "value, limits and their ramp")
    p.add_argument("unit")
    p.add_argument("name", help="CV or MV name (e.g. XMEAS7, XMV3, reactor_pressure_sp)")
    p.add_argument("--mode", choices=("auto", "manual", "off"), default=None,
                   help="CV: auto|off; MV: auto|manual|off")
    p.add_argument("--value", type=float, default=None, help="manual MV: value to hold")
    p.add_argument("--lo", type=float, default=None, help="operator low limit")
    p.add_argument("--hi", type=float, default=None, help="operator high limit")
    p.add_argument("--ramp-per-h", type=float, default=None,
                   help="rate a changed limit moves at, engineering units per hour")
    _common(p)
    p.set_defaults(func=run_variable)
    p = sub.add_parser("events", help="a unit's event log through the REST API: transitions, "
                                      "operator actions (who), alarms")
    p.add_argument("unit")
    p.add_argument("--since", default=None,
                   help="ISO 8601 time, e.g. 2026-12-01T22:30:00Z (no zone: UTC)")
    p.add_argument("--follow", action="store_true",
                   help="keep polling and print new events until Ctrl-C")
    p.add_argument("--poll-s", type=float, default=1.0, help="--follow: poll period, wall s")
    _common(p)
    p.set_defaults(func=run_events)

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

    body = {"grade": args.grade, "queue": bool(args.queue)}
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


def run_abort(args) -> int:
    import httpx

    with _client(args) as c:
        tid = args.id
        if tid is None:
            running = [v for v in _get(c, f"/api/v1/units/{args.unit}/transitions")
                       if v.get("state") in ("running", "pending")]
            if not running:
                raise CLIError(f"id: unit {args.unit!r} has no transition under way")
            tid = next((v["id"] for v in running if v["state"] == "running"), running[0]["id"])
        try:
            view = _check(c.delete(f"/api/v1/units/{args.unit}/transitions/{tid}"))
        except httpx.HTTPError as exc:
            raise CLIError(f"api: cannot reach {args.api}: {exc}") from exc
    if args.json:
        emit_json(view)
    else:
        print(f"transition {view['id']} -> {view['grade']}: {view['state']}")
    return 0


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


def _send(args, method: str, path: str, body: dict) -> dict:
    import httpx

    with _client(args) as c:
        try:
            return _check(c.request(method, path, json=body))
        except httpx.HTTPError as exc:
            raise CLIError(f"api: cannot reach {args.api}: {exc}") from exc


def run_mode(args) -> int:
    out = _send(args, "PUT", f"/api/v1/units/{args.unit}/mode", {"mode": args.mode})
    if args.json:
        emit_json(out)
    else:
        print(f"{args.unit}: controller {out['previous']} -> {out['mode']}")
    return 0


def run_variable(args) -> int:
    body = {k: getattr(args, k) for k in ("mode", "value", "lo", "hi", "ramp_per_h")
            if getattr(args, k) is not None}
    if not body:
        raise CLIError("variable: nothing to change; give --mode, --value, --lo, --hi or "
                       "--ramp-per-h")
    for k, v in body.items():
        if k != "mode" and not math.isfinite(v):
            raise CLIError(f"--{k.replace('_', '-')}: must be a finite number")
    v = _send(args, "PATCH", f"/api/v1/units/{args.unit}/variables/{args.name}", body)
    if args.json:
        emit_json(v)
    else:
        print(f"{args.unit}: {v['name']} mode {v.get('mode') or '-'}  value "
              f"{_fmt(v.get('value'), 0).strip()}  target {_fmt(v.get('target'), 0).strip()}  "
              f"limits [{_fmt(v.get('lo'), 0).strip()}, {_fmt(v.get('hi'), 0).strip()}] "
              f"{v.get('unit', '')}")
    return 0


#: The text view fits this many columns.
STATUS_WIDTH = 100


def _fmt(v, width: int) -> str:
    if v is None:
        return f"{'-':>{width}}"
    return f"{v:>{width}.5g}"


def _flag(v: dict, alarmed: set[str]) -> str:
    if v.get("mode") in ("manual", "off"):
        return "MAN" if v["mode"] == "manual" else "OFF"
    if v.get("at_limit") == "hi":
        return "HI"
    if v.get("at_limit") == "lo":
        return "LO"
    return "!" if v["name"] in alarmed else ""


def status_lines(st: dict, show_all: bool = False) -> list[str]:
    """The text view of a status document (each line at most :data:`STATUS_WIDTH`).

    CVs shown: the tracked ones, those at a limit or in alarm (``--all``: every CV);
    every MV. The last column marks a variable the operator holds (``MAN``) or
    switched off (``OFF``), one at its high or low limit (``HI``, ``LO``) or named by an
    alarm (``!``).
    """
    out = []
    tr = st.get("transition")
    grade = st.get("grade") or "-"
    if tr and tr.get("state") in ("pending", "running"):
        eta = tr.get("eta_s")
        grade = (f"{tr.get('from_grade') or grade} -> {tr['grade']}  {tr['state']} "
                 f"{100 * tr.get('progress', 0.0):.1f} %  ETA "
                 f"{'-' if eta is None else f'{eta / 3600:.2f} h'}")
    out.append(f"{st['unit']} ({st['plant']})  sample {st['sample']}  "
               f"t {st['process_time_s'] / 3600:.3f} h  grade {grade}")
    solve = st.get("solve_ms")
    out.append(f"controller {(st.get('controller_mode') or 'on').upper()} "
               f"{st.get('controller_status') or '-'}  solve "
               f"{'-' if solve is None else f'{solve:.3f} ms'} of {st['budget_ms']:.3g} ms  "
               f"deadline misses {st['deadline_misses']}  fallback {st['fallback_moves']}  "
               f"failed {st.get('failed_samples', 0)}")
    J = {k: v for k, v in (st.get("J") or {}).items() if v is not None}
    rms = {k: v for k, v in (st.get("prediction_rms") or {}).items() if v is not None}
    if st.get("active_model_name") or J:
        if rms:  # the index as the prediction error it stands for, in CV scales
            js = "prediction error (RMS, CV scales): " + "  ".join(
                f"{k} {v:.2f}" for k, v in rms.items())
        else:
            js = "J: " + "  ".join(f"{k} {v:.2e}" for k, v in J.items())
        out.append(f"active model {st.get('active_model_name') or '-'}  {js}"[:STATUS_WIDTH])
        if st.get("active_model_detail"):
            out.append(f"  ({st['active_model_detail']})"[:STATUS_WIDTH])
    targets = st.get("targets")
    if targets:  # the steady-state targets above the MPC, and what they relax
        relaxed = "  ".join(f"{r['cv']} {r['kind']} {r['limit']:g} relaxed by {r['amount']:.3g}"
                            for r in targets.get("relaxed") or ())
        out.append(f"steady-state targets {targets['status']}"
                   + (f": {relaxed}" if relaxed else "")[:STATUS_WIDTH])
    alarms = st.get("alarms", [])[-5:]
    text = " ".join(alarms)
    variables = st.get("variables") or []
    alarmed = {v["name"] for v in variables if v["name"] in text}
    head = (f"{'':<22} {'description':<23} {'value':>10} {'target':>10} {'lo':>8} {'hi':>8} "
            f"{'unit':<9} ")
    for kind, title in (("cv", "CV"), ("mv", "MV")):
        rows = [v for v in variables if v["kind"] == kind]
        if kind == "cv" and not show_all:
            rows = [v for v in rows if v.get("target") is not None or v.get("at_limit")
                    or v["name"] in alarmed]
        if not rows:
            continue
        out.append(title + head[len(title):])
        for v in rows:
            out.append(f"{v['name'][:22]:<22} {v['description'][:23]:<23} "
                       f"{_fmt(v['value'], 10)} {_fmt(v.get('target'), 10)} "
                       f"{_fmt(v['lo'], 8)} {_fmt(v['hi'], 8)} {v['unit'][:9]:<9} "
                       f"{_flag(v, alarmed)}")
    hidden = sum(v["kind"] == "cv" for v in variables) - sum(
        1 for ln in out if ln.split(" ")[0] in {v["name"] for v in variables if v["kind"] == "cv"})
    if hidden > 0:
        out.append(f"({hidden} more CVs: --all)")
    for a in alarms:
        out.append(f"alarm: {a}"[:STATUS_WIDTH])
    return out


def run_status(args) -> int:
    with _client(args) as c:
        st = _get(c, f"/api/v1/units/{args.unit}/status")
    if args.json:
        emit_json(st)
        return 0
    for line in status_lines(st, args.all):
        print(line)
    return 0


def event_line(view: dict) -> str:
    """One event as a line: time (UTC, to the second), kind, what happened, who."""
    from services.events import describe

    when = str(view.get("time", "")).replace("T", " ")[:19]
    return f"{when}  {view.get('kind', ''):<26} {describe(view)}  [{view.get('identity')}]"


def run_events(args) -> int:
    """Print the unit's events; with ``--follow`` poll for new ones until Ctrl-C (exit
    0). ``--json``: ``{"unit", "events": [...]}`` on the last line (with ``--follow``:
    one event object per line as they come)."""
    from urllib.parse import quote

    from services.events import MAX_LIMIT, parse_since_us

    if args.since is not None:
        try:
            parse_since_us(args.since)
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    if not 0 < args.poll_s < 3600:
        raise CLIError("poll-s: expected a period in (0, 3600) s")
    path = f"/api/v1/units/{quote(args.unit, safe='')}/events"
    state = {"since": args.since, "seen": set()}

    def fetch(c) -> list[dict]:
        since = state["since"]
        query = f"?limit={MAX_LIMIT}" + ("" if since is None else f"&since={quote(since)}")
        return [e for e in _get(c, path + query) if e.get("id") not in state["seen"]]

    def show(events: list[dict]) -> None:
        for e in events:
            print(json.dumps(e, separators=(",", ":")) if args.json else event_line(e),
                  flush=True)
        if events:  # ask again from the newest (inclusive, so skip the ones seen there)
            newest = events[-1]["time"]
            edge = {e["id"] for e in events if e["time"] == newest}
            state["seen"] = state["seen"] | edge if newest == state["since"] else edge
            state["since"] = newest

    with _client(args) as c:
        if not args.follow:
            events = fetch(c)
            if args.json:
                emit_json({"unit": args.unit, "events": events})
            else:
                show(events)
            return 0
        try:
            while True:
                show(fetch(c))
                time.sleep(args.poll_s)
        except KeyboardInterrupt:
            return 0
