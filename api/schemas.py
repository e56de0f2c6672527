"""Request and response bodies of the v1 REST API (pydantic v2)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["DisturbanceRequest", "TransitionRequest", "TransitionView", "Health",
           "UnitLiveliness", "UnitsResponse", "ErrorBody"]


class TransitionRequest(BaseModel):
    """``POST /api/v1/units/{unit}/transitions``."""

    model_config = ConfigDict(extra="forbid")

    grade: str = Field(min_length=1, max_length=64, description="target grade, e.g. mode2 or OPII")
    duration_h: float | None = Field(
        default=None, gt=0, le=1e4, allow_inf_nan=False,
        description="transition duration in process hours (first-order reference reaches "
                    "98 % after it); default: the unit's")
    queue: bool = Field(default=False, description="if another transition is under way, "
                        "wait for it instead of 409")


class DisturbanceRequest(BaseModel):
    """``POST /api/v1/units/{unit}/disturbances``: a plant disturbance switched by command."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=64,
                      description="IDV1..IDV20 for TE (value 1 = on, 0 = off), or a "
                                  "disturbance variable of a unit plant")
    value: float = Field(allow_inf_nan=False, description="new value")


class TransitionView(BaseModel):
    id: str
    unit: str
    grade: str
    from_grade: str | None = None
    state: Literal["pending", "running", "settled", "aborted", "failed"]
    progress: float
    ise: float
    eta_s: float | None = None
    eta_wall_s: float | None = None
    duration_s: float
    requested_t: float
    started_t: float | None = None
    ended_t: float | None = None
    target: list[float]
    detail: str = ""


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    zenoh_id: str


class UnitLiveliness(BaseModel):
    unit: str
    plant: bool
    controller: bool


class UnitsResponse(BaseModel):
    units: list[UnitLiveliness]


class ErrorBody(BaseModel):
    detail: Any
