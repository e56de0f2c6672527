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
           "VariableSettingView", "TransitionRequest", "TransitionView", "Health",
           "UnitLiveliness", "UnitsResponse", "ErrorBody", "GradesView", "GradeView",
           "StatusView", "VariableView", "DisturbancesView", "DisturbanceSet", "EventView",
           "KPIsView", "KPIWindowView", "ConstraintActivityView", "CostView", "TimeShareView",
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
    """The controller mode after ``PUT .../mode`` and the one before it."""

    unit: str
    mode: Literal["off", "warm", "on"]
    previous: Literal["off", "warm", "on"]


class VariableSettingView(BaseModel):
    """One CV's or MV's operator settings after ``PATCH .../variables/{name}``."""

    model_config = ConfigDict(extra="allow")

    name: str
    kind: Literal["cv", "mv", "dv"]
    mode: Literal["auto", "manual", "off"] | None = Field(description="auto, manual "
                                                          "(MVs) or off")
    value: float | None = Field(description="the value now")
    target: float | None = Field(description="an MV held in manual: its value; a CV: "
                                 "its reference")
    lo: float | None = Field(description="operator low limit in force (ramping)")
    hi: float | None = Field(description="operator high limit in force (ramping)")


class TransitionView(BaseModel):
    """One transition: its state, progress, ISE so far and ETA (process seconds)."""

    id: str = Field(min_length=1, description="transition id")
    unit: str
    grade: str = Field(description="target grade")
    from_grade: str | None = Field(default=None, description="grade it started from "
                                   "(None: the set points held were no grade's)")
    state: Literal["pending", "running", "settled", "aborted", "failed"]
    progress: float = Field(description="share of the set-point distance covered, 0..1")
    ise: float = Field(description="integral of the squared scaled tracking error so far, s")
    eta_s: float | None = Field(default=None, description="process seconds to the planned "
                                "end (None: ended)")
    eta_wall_s: float | None = Field(default=None, description="the same in wall seconds")
    duration_s: float = Field(description="planned duration, process s")
    requested_t: float = Field(description="process time of the request, s")
    started_t: float | None = Field(default=None, description="process time it ran from, s")
    ended_t: float | None = Field(default=None, description="process time it ended, s")
    target: list[float] = Field(description="set points of the target grade (tracked CVs)")
    detail: str = Field(default="", description="why it ended, or 'queued'")


class VariableView(BaseModel):
    """One CV, MV or measured disturbance of the status (engineering units)."""

    model_config = ConfigDict(extra="allow")

    name: str = Field(description="name on the wire, e.g. XMEAS7")
    tag: str = Field(description="plant tag, e.g. 'XMEAS 7'")
    description: str
    unit: str = Field(description="engineering unit, e.g. 'kPa gauge'")
    kind: Literal["cv", "mv", "dv"]
    value: float | None = None
    target: float | None = Field(default=None, description="a tracked CV's reference")
    lo: float | None = Field(default=None, description="low limit (None: none)")
    hi: float | None = Field(default=None, description="high limit (None: none)")
    at_limit: Literal["lo", "hi"] | None = None
    mode: str | None = Field(default=None, description="auto, manual or off (None: a DV)")


Numbers = dict[str, float | None]


class RelaxedLimitView(BaseModel):
    """A soft limit the steady-state targets do not meet."""

    cv: str
    kind: str = Field(description="min, max or spec")
    rank: int = Field(description="1 = most important")
    limit: float
    amount: float = Field(description="how far beyond the limit the targets are, CV units")


class TargetsView(BaseModel):
    """The steady-state targets the MPC steers to this sample."""

    status: str = Field(description="optimal (every limit met), relaxed (see relaxed), "
                                    "or plan, failed, unavailable (no targets this sample: "
                                    "the MPC on the plan's or its own references)")
    mv: dict[str, float] = Field(default_factory=dict, description="MV targets by name")
    cv: dict[str, float] = Field(default_factory=dict, description="CV targets by name")
    relaxed: list[RelaxedLimitView] = Field(default_factory=list)


class CompositionView(BaseModel):
    """The composition core of a TE unit: the MPC on the D share and G in product that
    plans a grade change between grades whose D and E valves leave the share free."""

    planning: bool = Field(description="whether its share is in force (through a grade "
                                       "change; else the G loop's)")
    model: str | None = Field(default=None, description="its active model (the grade "
                                                        "whose linearization it runs)")
    share: float | None = Field(default=None, description="the D share D/(D+E) it asks "
                                                          "for, 0-1")


class StatusView(BaseModel):
    """A controller's status. ``unit``, ``sample`` and ``alarms`` are always there; the
    rest as the controller reports it, and fields this version does not know pass
    through."""

    model_config = ConfigDict(extra="allow")

    unit: str
    sample: int = Field(description="latest sample processed (-1: none yet)")
    alarms: list[str] = Field(description="the latest alarms and notices, oldest first")
    plant: str | None = Field(default=None, description="plant model of the unit")
    process_time_s: float | None = Field(default=None, description="process time, s")
    speed: float | None = Field(default=None, description="process s per wall s")
    cv: Numbers | None = Field(default=None, description="measured CVs by name")
    ref: Numbers | None = Field(default=None, description="references of the tracked CVs")
    mv: Numbers | None = Field(default=None, description="last moves by name")
    variables: list[VariableView] | None = None
    active_model: int | None = Field(default=None, description="index of the active model")
    active_model_name: str | None = None
    active_model_detail: str | None = Field(default=None, description="what the active "
                                            "model is: fixed (of which grade) or adaptive, "
                                            "and where it was last re-initialized from")
    prediction_rms: Numbers | None = Field(default=None, description="each model's J as "
                                           "the RMS prediction error it stands for, in "
                                           "units of the CVs' scales")
    targets: TargetsView | None = Field(default=None, description="the sample's "
                                        "steady-state targets (units with a target layer "
                                        "above the MPC)")
    J: Numbers | None = Field(default=None, description="performance index per model")
    composition: CompositionView | None = Field(default=None, description="TE: the "
                                                "composition core (MPC strategies)")
    tuning: str | None = Field(default=None, description="the plant side's tuning set "
                               "the controller sends with its moves (TE MPC strategies: "
                               "'grade_change', 'steady' or 'steady_e_limited'); null: "
                               "the plant's default")
    solve_ms: float | None = Field(default=None, description="last controller step, ms")
    controller_status: str | None = None
    deadline_misses: int | None = None
    fallback_moves: int | None = None
    budget_ms: float | None = Field(default=None, description="timing budget per sample, ms")
    sample_ms: dict[str, float | int | None] | None = Field(
        default=None, description="p50, p99, max (ms) and n of the recent samples")
    slowest_sample: dict[str, float] | None = Field(
        default=None, description="phase breakdown of the slowest sample, ms")
    missed_samples: list[dict[str, float]] | None = Field(
        default=None, description="phase breakdowns of the latest samples over budget, ms")
    gc_pauses: dict[str, dict[str, float | int]] | None = None
    samples: int | None = None
    bad_measurements: int | None = None
    stale_measurements: int | None = None
    implausible_measurements: int | None = None
    foreign_measurements: int | None = None
    foreign_moves: int | None = None
    store: Literal["ok", "degraded"] | None = None
    store_error: str | None = None
    plant_incarnation: str | None = None
    failed_samples: int | None = None
    dropped_measurements: int | None = None
    plant_shutdown: bool | None = None
    plant_alive: bool | None = None
    grade: str | None = Field(default=None, description="grade held (None: in transition "
                              "or set points held after an abort)")
    transition: TransitionView | None = None
    restored_from_sample: int | None = None
    telemetry_samples: int | None = None


class GradeView(BaseModel):
    model_config = ConfigDict(extra="allow")

    setpoints: dict[str, float] = Field(description="CV set points of the grade by name")
    description: str = Field(default="", description="the grade as an engineer knows it "
                             "(TE: G/H mass ratio and production rate)")
    g_h_mass_ratio: str | None = Field(default=None, description="TE: G/H product mass "
                                       "ratio, e.g. '50/50'")
    product_kg_h: dict[str, float] | None = Field(default=None, description="TE: product "
                                                  "rates of G and H, kg/h (None: the "
                                                  "maximum-production modes)")
    stability: str | None = Field(default=None, description="stability type of the "
                                  "operating point")


class GradesView(BaseModel):
    """The grades (operating points) a unit can go to."""

    model_config = ConfigDict(extra="allow")

    unit: str
    grades: dict[str, GradeView]
    cvs: list[str] | None = Field(default=None, description="CV names, in set-point order")
    cv_units: list[str] | None = None
    current: str | None = Field(default=None, description="grade held now")


class DisturbancesView(BaseModel):
    """A plant's disturbances (TE: IDV1..IDV20, 1 = on) and whether it has shut down."""

    unit: str
    shutdown: bool | None = Field(default=None, description="the plant's interlocks "
                                  "shut it down")
    disturbances: dict[str, float]


class DisturbanceSet(BaseModel):
    """The plant's disturbances after a switch."""

    model_config = ConfigDict(extra="allow")

    disturbances: dict[str, float]


class EventView(BaseModel):
    """One event of the unit's log (transition state change, operator action, alarm)."""

    id: str = Field(min_length=1, description="stable id (unique per unit)")
    time: str = Field(description="wall time, ISO 8601 UTC with microseconds")
    process_time_h: float | None = Field(description="the unit's process time, h")
    kind: str = Field(description="transition.<state>, action.<what> (operator), "
                                  "alarm.raised or alarm.cleared")
    detail: dict[str, Any] = Field(description="what happened (depends on kind)")
    identity: str = Field(description="who: the identity of the REST caller for an "
                                      "operator action, 'controller' otherwise")


Share = Annotated[float, Field(ge=0.0, le=1.0)]


class TimeShareView(BaseModel):
    """How a window's time splits (shares 0..1, adding up to 1)."""

    on: Share | None = Field(description="ON and in control (the service factor)")
    fallback: Share | None = Field(description="ON, but the move written was not the "
                                   "controller's (held: a missed deadline, a failed step)")
    warm: Share | None = Field(description="WARM: computed, nothing written")
    off: Share | None = Field(description="OFF: nothing computed or written")
    down: Share | None = Field(description="no controller ran (a gap in the samples, "
                                           "e.g. a restart)")


class ConstraintActivityView(BaseModel):
    """One CV's or MV's constraint activity: shares of the samples ON at a limit."""

    name: str = Field(description="name on the wire, e.g. XMEAS7")
    kind: Literal["cv", "mv"]
    description: str = ""
    at_lo: Share | None = Field(description="share at (or below) its low limit")
    at_hi: Share | None = Field(description="share at (or above) its high limit")
    active: Share | None = Field(description="share at either limit")


class CostView(BaseModel):
    """Operating cost against the unit's base case, $/h (None: the unit has no cost)."""

    mean_usd_h: float | None = Field(description="time-mean operating cost over the window")
    base_usd_h: float | None = Field(description="the unit's base-case cost")
    vs_base_usd_h: float | None = Field(description="mean minus base (negative: cheaper "
                                        "than the base case)")
    hours: float = Field(ge=0.0, description="process hours with a cost in the window")


class KPIWindowView(BaseModel):
    """The KPIs over one window of process time."""

    window: str = Field(description="'since start', '1 h', '24 h'")
    length_h: float | None = Field(description="the window's length, h (None: since start)")
    hours: float = Field(ge=0.0, description="process hours the window covers so far")
    service_factor: Share | None = Field(description="share of the time ON and not in "
                                         "fallback")
    time_share: TimeShareView
    samples_on: int = Field(ge=0, description="samples ON counted for the activity")
    cost: CostView
    constraint_activity: list[ConstraintActivityView]
    prediction_rms: dict[str, float | None] = Field(
        description="each model's mean RMS prediction error, units of the CVs' scales")


class KPIsView(BaseModel):
    """A controller's key performance indicators (``GET .../kpis``)."""

    unit: str
    sample: int = Field(description="latest sample processed (-1: none yet)")
    samples: int = Field(ge=0, description="samples counted since the start (over "
                         "restarts)")
    process_time_s: float | None = Field(description="process time of the latest sample "
                                         "counted, s")
    base_cost_usd_h: float | None = Field(description="the unit's base-case operating cost")
    base_cost_origin: str | None = Field(description="where the base-case cost comes from")
    cost_now_usd_h: float | None = Field(description="operating cost at the latest sample")
    prediction_rms_now: dict[str, float | None] = Field(
        description="each model's RMS prediction error at the latest sample")
    windows: list[KPIWindowView] = Field(description="since start, then the trailing "
                                         "windows (1 h, 24 h)")


class Health(BaseModel):
    """The api node answers."""

    status: Literal["ok"]
    version: str
    zenoh_id: str


class UnitLiveliness(BaseModel):
    """Which nodes of a unit hold a liveliness token on the mesh."""

    unit: str
    plant: bool
    controller: bool


class UnitsResponse(BaseModel):
    """Units seen on the mesh."""

    units: list[UnitLiveliness]


class ErrorBody(BaseModel):
    """An error: what was wrong, in one line."""

    detail: str
