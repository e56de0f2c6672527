"""Request and response bodies of the v1 REST API (pydantic v2).

Request bodies are strict (``strict=True``: no ``true`` for 1.0, no ``"0.5"`` for
0.5; an integer is still a number), refuse unknown fields, NaN and infinities
(``allow_inf_nan=False``; Python's ``json`` reads ``1e400`` as infinity) and text
that is not valid Unicode (a lone surrogate such as ``"\\ud800"`` decodes to a
Python string that cannot be written as UTF-8).

Replies of the nodes are validated with the ``*View`` models before use
(:func:`api.app.create_app`): a reply that does not fit is a 502, never a 500.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

__all__ = ["DisturbanceRequest", "ModeRequest", "ModeView", "VariableRequest",
           "VariableView", "TransitionRequest", "TransitionView", "Health",
           "UnitLiveliness", "UnitsResponse", "ErrorBody", "GradesView", "StatusView",
           "valid_unicode"]


def valid_unicode(text: str) -> str:
    """``text`` if it can be written as UTF-8 (no lone surrogates), else ValueError."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("not valid Unicode (a lone surrogate)") from None
    return text


Text = Annotated[str, AfterValidator(valid_unicode)]
_STRICT = ConfigDict(extra="forbid", strict=True)


class TransitionRequest(BaseModel):
    """``POST /api/v1/units/{unit}/transitions``."""

    model_config = _STRICT

    grade: Text = Field(min_length=1, max_length=64,
                        description="target grade, e.g. mode2 or OPII")
    duration_h: float | None = Field(
        default=None, gt=0, le=1e4, allow_inf_nan=False,
        description="transition duration in process hours (first-order reference reaches "
                    "98 % after it); default: the unit's")
    queue: bool = Field(default=False, description="if another transition is under way, "
                        "wait for it instead of 409 (429 when the queue is full)")


class DisturbanceRequest(BaseModel):
    """``POST /api/v1/units/{unit}/disturbances``: a plant disturbance switched by command."""

    model_config = _STRICT

    name: Text = Field(min_length=1, max_length=64,
                       description="IDV1..IDV20 for TE (value 1 = on, 0 = off), or a "
                                   "disturbance variable of a unit plant")
    value: float = Field(allow_inf_nan=False, ge=-1e12, le=1e12, description="new value")


_NUMBER = {"allow_inf_nan": False, "ge": -1e12, "le": 1e12}


class VariableRequest(BaseModel):
    """``PATCH /api/v1/units/{unit}/variables/{name}``: an operator action on one CV or MV.

    Fields left out are unchanged; the controller checks the rest against the
    variable (its engineering range, what its controller offers for it) and applies it
    at the next sample.
    """

    model_config = _STRICT

    mode: Literal["auto", "manual", "off"] | None = Field(
        default=None, description="CV: auto (in the objective and its limits) or off (out "
        "of both); MV: auto (moved by the controller), manual (held at value, the other "
        "MVs planned around it) or off (out of the problem, held at its last value)")
    value: float | None = Field(default=None, **_NUMBER, description=(
        "manual MV: the value to hold, engineering units (default: the applied value)"))
    lo: float | None = Field(default=None, **_NUMBER, description=(
        "operator low limit, engineering units, inside the variable's engineering range"))
    hi: float | None = Field(default=None, **_NUMBER, description=(
        "operator high limit, engineering units, inside the variable's engineering range"))
    ramp_per_h: float | None = Field(default=None, gt=0, le=1e12, allow_inf_nan=False,
                                     description="rate a changed limit moves from the one "
                                     "in force, engineering units per process hour "
                                     "(default: the variable's last rate, else at once)")

    @model_validator(mode="after")
    def _limits_ordered(self):
        if self.lo is not None and self.hi is not None and self.lo > self.hi:
            raise ValueError("lo must not be above hi")
        return self


class ModeRequest(BaseModel):
    """``PUT /api/v1/units/{unit}/mode``: the controller mode."""

    model_config = _STRICT

    mode: Literal["off", "warm", "on"] = Field(description=(
        "off: nothing computed or written (the plant keeps its regulatory layer and last "
        "values); warm: computed and reported, nothing written, the models track the "
        "plant; on: moves written. Bumpless both ways"))


class ModeView(BaseModel):
    unit: str
    mode: Literal["off", "warm", "on"]
    previous: Literal["off", "warm", "on"]


class VariableView(BaseModel):
    """One entry of the status's ``variables``."""

    model_config = ConfigDict(extra="allow")

    name: str
    kind: Literal["cv", "mv", "dv"]
    mode: Literal["auto", "manual", "off"] | None
    value: float | None
    target: float | None
    lo: float | None
    hi: float | None


class TransitionView(BaseModel):
    id: str = Field(min_length=1)
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


class StatusView(BaseModel):
    """A controller's status: the fields the api relies on; the rest passes through."""

    model_config = ConfigDict(extra="allow")

    unit: str
    sample: int
    alarms: list[str]


class GradesView(BaseModel):
    model_config = ConfigDict(extra="allow")

    unit: str
    grades: dict[str, Any]


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
