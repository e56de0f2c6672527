"""FastAPI app of the api node: the v1 REST contract (README, "Using it") over Zenoh queries.

=========================================  ===========================================
``GET /health``                            liveness of the api node
``GET /api/v1/units``                      units seen on the mesh, plant/controller liveliness
``GET /api/v1/units/{unit}/status``        the controller's status
``GET /api/v1/units/{unit}/grades``        grades with their set points
``POST /api/v1/units/{unit}/transitions``  ``{"grade", "duration_h"?}`` → 202 + Location
``GET /api/v1/units/{unit}/transitions``   all transitions of the unit (history)
``GET .../transitions/{id}``               state, progress, ISE so far, ETA
``DELETE .../transitions/{id}``            abort and hold the current set points
``GET/POST /api/v1/units/{unit}/disturbances``  plant disturbances (TE IDVs), by command
=========================================  ===========================================

Errors: unknown unit/grade/transition → 404; malformed body → 422; a
transition while one runs → 409; no controller → 503; controller timeout →
504. Writes need the bearer token when ``SSMPC_API_TOKEN`` is set. Handlers are
plain functions (run in the thread pool) because Zenoh queries block.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import Depends, FastAPI, HTTPException, Path, Response

from api.auth import make_write_guard, token_from_env
from api.mesh import Mesh, MeshError
from api.schemas import (
    DisturbanceRequest,
    ErrorBody,
    Health,
    TransitionRequest,
    TransitionView,
    UnitLiveliness,
    UnitsResponse,
)
from services.io.messages import Reply

__all__ = ["create_app"]

UNIT = Path(..., min_length=1, max_length=64, description="unit name, e.g. te or cstr")

_ERR = {"model": ErrorBody}
#: Error answers of the routes that reach a node (documented in /openapi.json).
READ_ERRORS = {404: {**_ERR, "description": "unknown unit (or transition)"},
               502: {**_ERR, "description": "the node answered something unreadable"},
               503: {**_ERR, "description": "no live node for the unit (liveliness lost)"},
               504: {**_ERR, "description": "the node did not answer in time"}}
WRITE_ERRORS = {**READ_ERRORS,
                401: {**_ERR, "description": "missing or wrong bearer token"},
                409: {**_ERR, "description": "a transition is under way (use queue)"},
                422: {**_ERR, "description": "malformed body"}}
TID = Path(..., min_length=1, max_length=64, description="transition id")


def _version() -> str:
    try:
        return version("ssmpc")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0"


def _unwrap(reply: Reply):
    if reply.ok:
        return reply.data
    status = reply.code if reply.code in (400, 404, 409, 422) else 502
    raise HTTPException(status_code=status, detail=reply.error or f"controller code {reply.code}")


def create_app(mesh: Mesh, token: str | None = None, *, token_from_environment: bool = True
               ) -> FastAPI:
    """Build the app on an open :class:`Mesh`.

    ``token`` (or, when None and ``token_from_environment``, ``SSMPC_API_TOKEN``)
    protects the writes.
    """
    if token is None and token_from_environment:
        token = token_from_env()
    write_guard = make_write_guard(token)
    app = FastAPI(title="ssmpc", version=_version(),
                  description="Transition controller for continuous process plants (v1).")

    def forward(request, unit: str, action: str, args: dict | None):
        try:
            return _unwrap(request(unit, action, args))
        except MeshError as exc:
            raise HTTPException(status_code=exc.status, detail=exc.detail) from exc

    def call(unit: str, action: str, args: dict | None = None):
        return forward(mesh.request, unit, action, args)

    @app.get("/health", response_model=Health)
    def health() -> Health:
        return Health(status="ok", version=_version(), zenoh_id=str(mesh.session.info.zid()))

    @app.get("/api/v1/units", response_model=UnitsResponse)
    def units() -> UnitsResponse:
        return UnitsResponse(units=[UnitLiveliness(unit=u, **roles)
                                    for u, roles in mesh.units().items()])

    @app.get("/api/v1/units/{unit}/status", responses=READ_ERRORS)
    def status(unit: str = UNIT) -> dict:
        return call(unit, "status")

    @app.get("/api/v1/units/{unit}/grades", responses=READ_ERRORS)
    def grades(unit: str = UNIT) -> dict:
        return call(unit, "grades")

    @app.post("/api/v1/units/{unit}/transitions", status_code=202, response_model=TransitionView,
              dependencies=[Depends(write_guard)], responses=WRITE_ERRORS)
    def create_transition(body: TransitionRequest, response: Response,
                          unit: str = UNIT) -> dict:
        args = {"op": "create", "grade": body.grade, "queue": body.queue}
        if body.duration_h is not None:
            args["duration_s"] = body.duration_h * 3600.0
        view = call(unit, "transition", args)
        response.headers["Location"] = f"/api/v1/units/{unit}/transitions/{view['id']}"
        return view

    @app.get("/api/v1/units/{unit}/transitions", responses=READ_ERRORS)
    def list_transitions(unit: str = UNIT) -> list[dict]:
        return call(unit, "transition", {"op": "list"})

    @app.get("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
             responses=READ_ERRORS)
    def get_transition(unit: str = UNIT, tid: str = TID) -> dict:
        return call(unit, "transition", {"op": "get", "id": tid})

    @app.delete("/api/v1/units/{unit}/transitions/{tid}", response_model=TransitionView,
                dependencies=[Depends(write_guard)], responses=WRITE_ERRORS)
    def abort_transition(unit: str = UNIT, tid: str = TID) -> dict:
        return call(unit, "transition", {"op": "abort", "id": tid})

    def call_plant(unit: str, action: str, args: dict | None = None):
        return forward(mesh.request_plant, unit, action, args)

    @app.get("/api/v1/units/{unit}/disturbances", responses=READ_ERRORS)
    def disturbances(unit: str = UNIT) -> dict:
        status = call_plant(unit, "status")
        return {"unit": unit, "shutdown": status.get("shutdown"),
                "disturbances": call_plant(unit, "disturbance_list")}

    @app.post("/api/v1/units/{unit}/disturbances", dependencies=[Depends(write_guard)],
              responses=WRITE_ERRORS)
    def set_disturbance(body: DisturbanceRequest, unit: str = UNIT) -> dict:
        return call_plant(unit, "disturbance", {"name": body.name, "value": body.value})

    return app
