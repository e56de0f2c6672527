"""FastAPI app of the api node: the v1 REST contract (README, "Using it") over Zenoh queries.

=========================================  ===========================================
``GET /health``                            liveness of the api node
``GET /api/v1/units``                      units seen on the mesh, plant/controller liveliness
``GET /api/v1/units/{unit}/status``        the controller's status
``GET /api/v1/units/{unit}/grades``        grades with their set points
``POST /api/v1/units/{unit}/transitions``  ``{"grade", "duration_h"?, "queue"?}`` → 202 +
                                           Location; ``Idempotency-Key`` honoured
``GET /api/v1/units/{unit}/transitions``   all transitions of the unit (history)
``GET .../transitions/{id}``               state, progress, ISE so far, ETA
``DELETE .../transitions/{id}``            abort and hold the current set points
``GET/POST /api/v1/units/{unit}/disturbances``  plant disturbances (TE IDVs), by command
``PATCH .../variables/{name}``             operator action on a CV or MV (mode, value,
                                           limits, ramp)
``PUT /api/v1/units/{unit}/mode``          controller mode off / warm / on
``GET /api/v1/units/{unit}/events``        the unit's event log (``since`` ISO, ``limit``)
``GET /api/v1/units/{unit}/kpis``          service factor, constraint activity, cost vs
                                           base case, prediction error per model
``GET /docs``, ``GET /redoc``              the OpenAPI document, read in a browser
=========================================  ===========================================

Every route has a summary, a description and a typed response model
(:mod:`api.schemas`); ``/docs`` (Swagger UI) and ``/redoc`` load their scripts and
styles from this server (the ``fastapi-offline`` package ships them), so they work
on a plant network without the internet.

Writes carry the identity the request authenticated as (:mod:`api.auth`) to the
controller, which records the operator action with it (:mod:`services.events`).

Errors: unknown unit/grade/transition → 404; malformed body (NaN, infinities,
out-of-range numbers, bad Unicode, wrong types) → 422 with a message that never
echoes the input; a transition while one runs → 409; a full transition queue → 429;
a malformed reply from a node → 502; no controller, the store unable to commit, or
the api's mesh pool full → 503; controller timeout → 504. Writes need the bearer
token when one is set.

The handlers are coroutines; every Zenoh query runs on the api's own bounded pool
(:class:`api.mesh_pool.MeshPool`), so a controller that never answers cannot hold
``/health`` up. Every reply is validated (:mod:`api.schemas` views) before use.

``Idempotency-Key`` (printable ASCII, 1-255 characters) on a POST of a transition:
the same key gives back the transition it made (same id, no second one), also after
a controller restart (the key is stored with the transition); the same key with
another body is a 422.
"""

from __future__ import annotations

import json
from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi_offline import FastAPIOffline
from pydantic import TypeAdapter, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from api.auth import make_write_guard, token_from_env
from api.docs_policy import DocsPolicy
from api.mesh import Mesh, MeshError
from api.mesh_pool import MeshLimits, MeshPool
from api.schemas import (
    DisturbanceRequest,
    DisturbanceSet,
    DisturbancesView,
    ErrorBody,
    EventView,
    GradesView,
    Health,
    KPIsView,
    ModeRequest,
    ModeView,
    StatusView,
    TransitionRequest,
    TransitionView,
    UnitLiveliness,
    UnitsResponse,
    VariableRequest,
    VariableSettingView,
)
from services.events import MAX_LIMIT, parse_since_us
from services.events_query import DEFAULT_LIMIT
from services.io.messages import Reply

__all__ = ["create_app", "SafeJSONResponse", "IDEMPOTENCY_KEY_MAX"]

def _unit_path():
    """The ``{unit}`` path parameter (a new one per route: FastAPI writes the parameter's
    alias into the object it is given)."""
    return Path(..., min_length=1, max_length=64, description="unit name, e.g. te or cstr")


def _tid_path():
    """The ``{tid}`` path parameter (a new one per route)."""
    return Path(..., min_length=1, max_length=64, description="transition id")


def _variable_path():
    """The ``{name}`` path parameter of a CV or MV (a new one per route)."""
    return Path(..., min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$",
                description="a CV or MV name, e.g. XMEAS7 or reactor_pressure_sp")


#: Longest ``Idempotency-Key`` accepted, characters.
IDEMPOTENCY_KEY_MAX = 255

_ERR = {"model": ErrorBody}
#: Error answers of the routes that reach a node (documented in /openapi.json).
READ_ERRORS = {404: {**_ERR, "description": "unknown unit (or transition)"},
               422: {**_ERR, "description": "malformed path or query parameter"},
               502: {**_ERR, "description": "the node answered something unreadable"},
               503: {**_ERR, "description": "no live node for the unit (liveliness lost), "
                                            "the store cannot commit, or the api is busy"},
               504: {**_ERR, "description": "the node did not answer in time"}}
WRITE_ERRORS = {**READ_ERRORS,
                401: {**_ERR, "description": "missing or wrong bearer token"},
                409: {**_ERR, "description": "a transition is under way (use queue)"},
                422: {**_ERR, "description": "malformed body"},
                429: {**_ERR, "description": "the transition queue is full"}}
#: Codes of a node's error reply passed on as they are (anything else is a 502).
PASSED_ON = (400, 404, 409, 422, 429, 503)

#: FastAPI's answer (400) to a body ``json.loads`` cannot read (bad UTF-8, a number
#: of more digits than Python converts): a malformed body, so 422 here.
_BODY_UNREADABLE = "There was an error parsing the body"
_VIEW = TypeAdapter(TransitionView)
_VIEWS = TypeAdapter(list[TransitionView])
_STATUS = TypeAdapter(StatusView)
_GRADES = TypeAdapter(GradesView)
_OBJECT = TypeAdapter(dict[str, Any])
_VARIABLE = TypeAdapter(VariableSettingView)
_MODE = TypeAdapter(ModeView)
_NUMBERS = TypeAdapter(dict[str, float])
_DISTURBANCE_SET = TypeAdapter(DisturbanceSet)
_EVENTS = TypeAdapter(list[EventView])
_KPIS = TypeAdapter(KPIsView)


class SafeJSONResponse(JSONResponse):
    """JSON written as ASCII: any text (a lone surrogate included) can be sent."""

    def render(self, content: Any) -> bytes:
        return json.dumps(content, ensure_ascii=True, allow_nan=False,
                          separators=(",", ":")).encode("ascii")


def _printable(text: Any) -> str:
    """``text`` as a string safe to write (undecodable characters escaped)."""
    return str(text).encode("utf-8", "backslashreplace").decode("utf-8")


def _validation_message(errors) -> str:
    """One line per error, ``where: what``, without the input (it may not be writable)."""
    parts = []
    for e in errors:
        if e.get("type") == "json_invalid":
            where = e.get("loc", ("body", "?"))[-1]
            parts.append(f"body: not valid JSON (at character {_printable(where)})")
            continue
        loc = ".".join(_printable(x) for x in e.get("loc", ()) if x != "body") or "body"
        parts.append(f"{loc}: {_printable(e.get('msg', 'invalid'))}")
    return "; ".join(parts) or "malformed request"


def _version() -> str:
    try:
        return version("ssmpc")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0"


def _unwrap(reply: Reply, who: str):
    if reply.ok:
        return reply.data
    status = reply.code if reply.code in PASSED_ON else 502
    raise HTTPException(status_code=status, detail=reply.error or f"{who} code {reply.code}")


def _checked(data, adapter: TypeAdapter, who: str):
    """``data`` validated by ``adapter`` (models where it has them), or a 502 that
    says why."""
    try:
        value = adapter.validate_python(data)
    except ValidationError as exc:
        raise HTTPException(status_code=502, detail=f"{who} sent a malformed reply: "
                            f"{_validation_message(exc.errors())}") from exc
    # the validated value itself: a route returns it to FastAPI, which then passes the
    # model through instead of validating the whole reply a second time (a TE status:
    # ~0.26 against ~0.6 ms of the api's time per GET, measured in-process)
    return value


def _idempotency_key(raw: str | None) -> str | None:
    if raw is None:
        return None
    key = raw.strip()
    if not (1 <= len(key) <= IDEMPOTENCY_KEY_MAX) or not all(" " <= c <= "~" for c in key):
        raise HTTPException(status_code=422, detail=(
            f"Idempotency-Key: expected 1..{IDEMPOTENCY_KEY_MAX} printable ASCII characters"))
    return key


def create_app(mesh: Mesh, token: str | None = None, *, token_from_environment: bool = True,
               limits: MeshLimits | None = None) -> FastAPI:
    """Build the app on an open :class:`Mesh`.

    ``token`` (or, when None and ``token_from_environment``, ``SSMPC_API_TOKEN``)
    protects the writes; ``limits`` bound the queries to the mesh.
    """
    if token is None and token_from_environment:
        token = token_from_env()
    write_guard = make_write_guard(token)
    pool = MeshPool(limits)
    app: FastAPI = FastAPIOffline(
        title="ssmpc", version=_version(), default_response_class=SafeJSONResponse,
        description=("Transition controller for continuous process plants (v1): grades, "
                     "transitions, status, disturbances, the event log and the KPIs of each "
                     "unit. "
                     "Writes need `Authorization: Bearer <token>` when the api has one."),
        # Swagger UI's online validator badge would call a server on the internet
        swagger_ui_parameters={"validatorUrl": None})
    app.state.mesh_pool = pool
    # the OpenAPI pages may load nothing from off this server (api.docs_policy)
    app.add_middleware(DocsPolicy, paths=("/docs", "/redoc", "/docs/oauth2-redirect"))

    @app.exception_handler(RequestValidationError)
    async def malformed(request: Request, exc: RequestValidationError):
        return SafeJSONResponse(status_code=422,
                                content={"detail": _validation_message(exc.errors())})

    @app.exception_handler(StarletteHTTPException)  # FastAPI's own errors are Starlette's
    async def http_error(request: Request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 400 and detail == _BODY_UNREADABLE:  # FastAPI's own
            return SafeJSONResponse(status_code=422, content={"detail": (
                "body: not readable as JSON (not UTF-8, or a number too long to read)")})
        return SafeJSONResponse(status_code=exc.status_code,
                                content={"detail": _printable(detail)},
                                headers=getattr(exc, "headers", None))

    async def forward(request, who: str, unit: str, action: str, args: dict | None,
                      adapter: TypeAdapter):
        try:
            reply = await pool.run(request, unit, action, args)
        except MeshError as exc:
            raise HTTPException(status_code=exc.status, detail=exc.detail) from exc
        return _checked(_unwrap(reply, who), adapter, who)

    async def call(unit: str, action: str, args: dict | None, adapter: TypeAdapter):
        return await forward(mesh.request, "controller", unit, action, args, adapter)

    async def call_plant(unit: str, action: str, args: dict | None, adapter: TypeAdapter):
        return await forward(mesh.request_plant, "plant", unit, action, args, adapter)

    @app.get("/health", response_model=Health, summary="Liveness of the api node",
             description="Answers while the api node runs, also when a controller hangs; "
                         "no query to the mesh.")
    async def health() -> Health:
        return Health(status="ok", version=_version(), zenoh_id=str(mesh.session.info.zid()))

    @app.get("/api/v1/units", response_model=UnitsResponse,
             summary="Units on the mesh",
             description="Every unit whose plant or controller node holds a liveliness "
                         "token, and which of the two do.")
    async def units() -> UnitsResponse:
        return UnitsResponse(units=[UnitLiveliness(unit=u, **roles)
                                    for u, roles in mesh.units().items()])

    @app.get("/api/v1/units/{unit}/status", response_model=StatusView, responses=READ_ERRORS,
             summary="A unit's controller status",
             description="Process time, sample, grade and transition, every CV/MV/DV with "
                         "its limits (`variables`), active model and J values, last solve "
                         "time, deadline misses, store health and the latest alarms.")
    async def status(unit: str = _unit_path()) -> StatusView:
        return await call(unit, "status", None, _STATUS)

    @app.get("/api/v1/units/{unit}/grades", response_model=GradesView, responses=READ_ERRORS,
             summary="Grades a unit can go to",
             description="The operating points (TE mode0..mode6, unit plants OPI..OPIII) "
                         "with their CV set points, description and stability type.")
    async def grades(unit: str = _unit_path()) -> GradesView:
        return await call(unit, "grades", None, _GRADES)

    @app.post("/api/v1/units/{unit}/transitions", status_code=202, response_model=TransitionView,
              responses=WRITE_ERRORS, summary="Request a grade transition",
              description="Starts a transition to `grade` along a first-order reference "
                          "(202 and `Location`). While one is under way: 409, or with "
                          "`queue` it waits (429 when the queue is full). Committed to the "
                          "store, with the operator action and its identity, before the "
                          "202; the store unable to commit is a 503. `Idempotency-Key`: "
                          "the same key gives back the same transition.")
    async def create_transition(
            body: TransitionRequest, response: Response, unit: str = _unit_path(),
            identity: str = Depends(write_guard),
            idempotency_key: Annotated[str | None, Header(
                alias="Idempotency-Key",
                description="the same key gives back the same transition")] = None,
    ) -> TransitionView:
        key = _idempotency_key(idempotency_key)
        args = {"op": "create", "grade": body.grade, "queue": body.queue,
                "identity": identity}
        if body.duration_h is not None:
            args["duration_s"] = body.duration_h * 3600.0
        if key is not None:
            args["idempotency_key"] = key
        view = await call(unit, "transition", args, _VIEW)
        response.headers["Location"] = f"/api/v1/units/{unit}/transitions/{view.id}"
        return view

    @app.get("/api/v1/units/{unit}/transitions", response_model=list[TransitionView],
             responses=READ_ERRORS, summary="A unit's transitions",
             description="Every transition of the unit, oldest first, as the store has "
                         "them (also those before a controller restart).")
    async def list_transitions(unit: str = _unit_path()) -> list[TransitionView]:
        return await call(unit, "transition", {"op": "list"}, _VIEWS)

    @app.get("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
             responses=READ_ERRORS, summary="One transition",
             description="State (pending, running, settled, aborted, failed), progress, "
                         "ISE so far and ETA of one transition.")
    async def get_transition(unit: str = _unit_path(), tid: str = _tid_path()
                             ) -> TransitionView:
        return await call(unit, "transition", {"op": "get", "id": tid}, _VIEW)

    @app.delete("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
                responses=WRITE_ERRORS, summary="Abort a transition",
                description="Holds the set points of this moment; control goes on. A "
                            "queued one leaves the queue. Committed with the operator "
                            "action before the answer (503 if the store cannot: the "
                            "transition then goes on as it was).")
    async def abort_transition(unit: str = _unit_path(), tid: str = _tid_path(),
                               identity: str = Depends(write_guard)) -> TransitionView:
        return await call(unit, "transition", {"op": "abort", "id": tid,
                                               "identity": identity}, _VIEW)

    @app.get("/api/v1/units/{unit}/disturbances", response_model=DisturbancesView,
             responses=READ_ERRORS, summary="A plant's disturbances",
             description="The plant node's disturbance values (TE: IDV1..IDV20, 1 = on) "
                         "and whether its interlocks shut it down.")
    async def disturbances(unit: str = _unit_path()) -> dict:
        status = await call_plant(unit, "status", None, _OBJECT)
        return {"unit": unit, "shutdown": status.get("shutdown"),
                "disturbances": await call_plant(unit, "disturbance_list", None, _NUMBERS)}

    @app.post("/api/v1/units/{unit}/disturbances", response_model=DisturbanceSet,
              dependencies=[Depends(write_guard)], responses=WRITE_ERRORS,
              summary="Switch a plant disturbance",
              description="Sets one disturbance of the simulated plant (TE: IDVk 1 on, "
                          "0 off) by command to its plant node.")
    async def set_disturbance(body: DisturbanceRequest, unit: str = _unit_path()
                              ) -> DisturbanceSet:
        return await call_plant(unit, "disturbance", {"name": body.name, "value": body.value},
                                _DISTURBANCE_SET)

    @app.get("/api/v1/units/{unit}/events", response_model=list[EventView],
             responses={**READ_ERRORS,
                        422: {**_ERR, "description": "`since` is not an ISO 8601 time"},
                        503: {**_ERR, "description": "no live controller, or its store "
                                                     "cannot be read"}},
             summary="A unit's event log",
             description="Transition state changes, operator actions (with the identity "
                         "that made them) and controller alarms raised and cleared, "
                         "oldest first, from the controller's store (they survive its "
                         "restarts). `since`: events at or after that time; `limit`: at "
                         "most that many, the oldest (ask again from the last one's "
                         "`time` for more).")
    async def events(
            unit: str = _unit_path(),
            since: Annotated[str | None, Query(
                max_length=64, description="ISO 8601 time, e.g. 2026-12-01T22:30:00Z "
                                           "(no zone: UTC)")] = None,
            limit: Annotated[int, Query(ge=1, le=MAX_LIMIT,
                                        description="most events returned")] = DEFAULT_LIMIT,
    ) -> list[EventView]:
        args: dict[str, Any] = {"limit": limit}
        if since is not None:
            try:
                args["since_us"] = parse_since_us(since)
            except ValueError as exc:
                raise HTTPException(status_code=422, detail=str(exc)) from None
        return await call(unit, "events", args, _EVENTS)

    @app.get("/api/v1/units/{unit}/kpis", response_model=KPIsView, responses=READ_ERRORS,
             summary="A unit's key performance indicators",
             description="As an APC package reports them, since the start and over the "
                         "last 1 h and 24 h of process time: the service factor (share of "
                         "the time ON and not in fallback; WARM, OFF and time without a "
                         "controller count against it), the constraint activity of each "
                         "CV and MV (share of the samples ON at its low or high limit), "
                         "the operating cost against the unit's base case ($/h; TE: "
                         "Downs & Vogel, base case 170.6 $/h) and each model's mean RMS "
                         "prediction error. Kept in the controller's checkpoint: a "
                         "restart goes on counting.")
    async def kpis(unit: str = _unit_path()) -> KPIsView:
        return await call(unit, "kpis", None, _KPIS)

    @app.patch("/api/v1/units/{unit}/variables/{name}", response_model=VariableSettingView,
               responses={**WRITE_ERRORS,
                          404: {**_ERR, "description": "unknown unit or variable"}},
               summary="Operator action on one CV or MV",
               description="A CV `auto` or `off` (off: out of the objective and its "
                           "limits); an MV `auto`, `manual` (held at `value`, the MPC "
                           "plans the others around it) or `off` (held at its last "
                           "value); operator limits `lo`/`hi` that ramp at `ramp_per_h` "
                           "from the ones in force. Validated (finite, lo <= hi, within "
                           "the variable's range: 422), applied at the next sample, "
                           "committed with the operator action before the answer (503 "
                           "if the store cannot: nothing changes), kept over a restart.")
    async def patch_variable(body: VariableRequest, unit: str = _unit_path(),
                             name: str = _variable_path(),
                             identity: str = Depends(write_guard)) -> VariableSettingView:
        args = {"name": name, **body.model_dump(exclude_none=True), "identity": identity}
        return await call(unit, "variable", args, _VARIABLE)

    @app.put("/api/v1/units/{unit}/mode", response_model=ModeView, responses=WRITE_ERRORS,
             summary="Controller mode off, warm or on",
             description="off: nothing computed or written (the plant keeps its "
                         "regulatory layer); warm: computed and reported, nothing "
                         "written, the models track the plant; on: moves written. "
                         "Bumpless both ways. Not off or warm while a transition runs "
                         "(409), no transition unless on. Committed with the operator "
                         "action before the answer.")
    async def put_mode(body: ModeRequest, unit: str = _unit_path(),
                       identity: str = Depends(write_guard)) -> ModeView:
        return await call(unit, "mode", {"mode": body.mode, "identity": identity}, _MODE)

    return app
