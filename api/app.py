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
=========================================  ===========================================

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

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import TypeAdapter, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from api.auth import make_write_guard, token_from_env
from api.mesh import Mesh, MeshError
from api.mesh_pool import MeshLimits, MeshPool
from api.schemas import (
    DisturbanceRequest,
    ErrorBody,
    GradesView,
    Health,
    ModeRequest,
    ModeView,
    StatusView,
    TransitionRequest,
    TransitionView,
    UnitLiveliness,
    UnitsResponse,
    VariableRequest,
    VariableView,
)
from services.io.messages import Reply

__all__ = ["create_app", "SafeJSONResponse", "IDEMPOTENCY_KEY_MAX"]

UNIT = Path(..., min_length=1, max_length=64, description="unit name, e.g. te or cstr")
#: Longest ``Idempotency-Key`` accepted, characters.
IDEMPOTENCY_KEY_MAX = 255

_ERR = {"model": ErrorBody}
#: Error answers of the routes that reach a node (documented in /openapi.json).
READ_ERRORS = {404: {**_ERR, "description": "unknown unit (or transition)"},
               502: {**_ERR, "description": "the node answered something unreadable"},
               503: {**_ERR, "description": "no live node for the unit (liveliness lost), "
                                            "the store cannot commit, or the api is busy"},
               504: {**_ERR, "description": "the node did not answer in time"}}
WRITE_ERRORS = {**READ_ERRORS,
                401: {**_ERR, "description": "missing or wrong bearer token"},
                409: {**_ERR, "description": "a transition is under way (use queue)"},
                422: {**_ERR, "description": "malformed body"},
                429: {**_ERR, "description": "the transition queue is full"}}
TID = Path(..., min_length=1, max_length=64, description="transition id")
VARIABLE = Path(..., min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$",
                description="a CV or MV name, e.g. XMEAS7 or reactor_pressure_sp")
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
_VARIABLE = TypeAdapter(VariableView)
_MODE = TypeAdapter(ModeView)
_NUMBERS = TypeAdapter(dict[str, float])


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
    """``data`` validated by ``adapter`` (plain Python again), or a 502 that says why."""
    try:
        value = adapter.validate_python(data)
    except ValidationError as exc:
        raise HTTPException(status_code=502, detail=f"{who} sent a malformed reply: "
                            f"{_validation_message(exc.errors())}") from exc
    return adapter.dump_python(value)


def _who(request: Request) -> str:
    """The identity stored with an operator action: the api and the client's address
    (one bearer token is shared, so the address is what tells operators apart)."""
    client = request.client
    return f"api ({client.host})" if client is not None else "api"


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
    app = FastAPI(title="ssmpc", version=_version(), default_response_class=SafeJSONResponse,
                  description="Transition controller for continuous process plants (v1).")
    app.state.mesh_pool = pool

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

    @app.get("/health", response_model=Health)
    async def health() -> Health:
        return Health(status="ok", version=_version(), zenoh_id=str(mesh.session.info.zid()))

    @app.get("/api/v1/units", response_model=UnitsResponse)
    async def units() -> UnitsResponse:
        return UnitsResponse(units=[UnitLiveliness(unit=u, **roles)
                                    for u, roles in mesh.units().items()])

    @app.get("/api/v1/units/{unit}/status", responses=READ_ERRORS)
    async def status(unit: str = UNIT) -> dict:
        return await call(unit, "status", None, _STATUS)

    @app.get("/api/v1/units/{unit}/grades", responses=READ_ERRORS)
    async def grades(unit: str = UNIT) -> dict:
        return await call(unit, "grades", None, _GRADES)

    @app.post("/api/v1/units/{unit}/transitions", status_code=202, response_model=TransitionView,
              dependencies=[Depends(write_guard)], responses=WRITE_ERRORS)
    async def create_transition(
            body: TransitionRequest, response: Response, unit: str = UNIT,
            idempotency_key: Annotated[str | None, Header(
                alias="Idempotency-Key",
                description="the same key gives back the same transition")] = None) -> dict:
        key = _idempotency_key(idempotency_key)
        args = {"op": "create", "grade": body.grade, "queue": body.queue}
        if body.duration_h is not None:
            args["duration_s"] = body.duration_h * 3600.0
        if key is not None:
            args["idempotency_key"] = key
        view = await call(unit, "transition", args, _VIEW)
        response.headers["Location"] = f"/api/v1/units/{unit}/transitions/{view['id']}"
        return view

    @app.get("/api/v1/units/{unit}/transitions", responses=READ_ERRORS)
    async def list_transitions(unit: str = UNIT) -> list[dict]:
        return await call(unit, "transition", {"op": "list"}, _VIEWS)

    @app.get("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
             responses=READ_ERRORS)
    async def get_transition(unit: str = UNIT, tid: str = TID) -> dict:
        return await call(unit, "transition", {"op": "get", "id": tid}, _VIEW)

    @app.delete("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
                dependencies=[Depends(write_guard)], responses=WRITE_ERRORS)
    async def abort_transition(unit: str = UNIT, tid: str = TID) -> dict:
        return await call(unit, "transition", {"op": "abort", "id": tid}, _VIEW)

    @app.get("/api/v1/units/{unit}/disturbances", responses=READ_ERRORS)
    async def disturbances(unit: str = UNIT) -> dict:
        status = await call_plant(unit, "status", None, _OBJECT)
        return {"unit": unit, "shutdown": status.get("shutdown"),
                "disturbances": await call_plant(unit, "disturbance_list", None, _NUMBERS)}

    @app.post("/api/v1/units/{unit}/disturbances", dependencies=[Depends(write_guard)],
              responses=WRITE_ERRORS)
    async def set_disturbance(body: DisturbanceRequest, unit: str = UNIT) -> dict:
        return await call_plant(unit, "disturbance", {"name": body.name, "value": body.value},
                                _OBJECT)

    @app.patch("/api/v1/units/{unit}/variables/{name}", response_model=VariableView,
               dependencies=[Depends(write_guard)],
               responses={**WRITE_ERRORS,
                          404: {**_ERR, "description": "unknown unit or variable"}})
    async def patch_variable(body: VariableRequest, request: Request, unit: str = UNIT,
                             name: str = VARIABLE) -> dict:
        args = {"name": name, **body.model_dump(exclude_none=True),
                "identity": _who(request)}
        return await call(unit, "variable", args, _VARIABLE)

    @app.put("/api/v1/units/{unit}/mode", response_model=ModeView,
             dependencies=[Depends(write_guard)], responses=WRITE_ERRORS)
    async def put_mode(body: ModeRequest, request: Request, unit: str = UNIT) -> dict:
        return await call(unit, "mode", {"mode": body.mode, "identity": _who(request)},
                          _MODE)

    return app
