"""Describing plants for the command line: variables, operating points, stability.

Shared by ``ssmpc plants``, ``ssmpc linearize`` and ``ssmpc sim``.
"""

from __future__ import annotations

import math

from plant_sim import get_plant
from plant_sim.base import PlantInputError, PlantModel, Variable
from services.output import CLIError

__all__ = ["parse_options", "build_plant", "describe_plant", "variable_dict"]


def parse_options(items: list[str] | None) -> dict:
    """``["gamma=inf", "sigma=ref94"]`` -> ``{"gamma": inf, "sigma": "ref94"}``."""
    out: dict = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise CLIError(f"option: expected KEY=VALUE, got {item!r}")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value.strip()
    return out


def build_plant(name: str, options: dict | None = None) -> PlantModel:
    """Build a plant; constructor keyword errors become errors naming the option."""
    try:
        return get_plant(name, **(options or {}))
    except TypeError as exc:
        raise CLIError(f"option: plant {name!r} does not accept {sorted(options or {})}: "
                       f"{exc}") from exc


def variable_dict(v: Variable) -> dict:
    return {"name": v.name, "unit": v.unit, "description": v.description,
            "lower": v.lower if math.isfinite(v.lower) else None,
            "upper": v.upper if math.isfinite(v.upper) else None}


#: Plants with more outputs than this list no outputs per operating point (the TE
#: measurement model is compiled on first use, which would dominate a listing).
MAX_LISTED_OUTPUTS = 12


def describe_plant(plant: PlantModel) -> dict:
    """JSON-ready description of a plant and its operating points.

    ``y`` of an operating point is ``None`` for plants with more than
    :data:`MAX_LISTED_OUTPUTS` outputs.
    """
    ops = []
    for op in plant.operating_points.values():
        y = None
        if plant.ny <= MAX_LISTED_OUTPUTS:
            try:
                y = plant.outputs(op.x, op.u).tolist()
            except (ValueError, PlantInputError):  # pragma: no cover - defensive
                y = None
        ops.append({
            "name": op.name, "stability": op.stability,
            "stability_detail": op.stability_detail, "valid": op.valid,
            "confidence": op.confidence, "description": op.description,
            "x": op.x.tolist(), "u": op.u.tolist(), "d": op.d.tolist(), "y": y,
        })
    return {
        "name": plant.name, "title": plant.title, "time_unit": plant.time_unit,
        "reconstructed": bool(plant.reconstructed),
        "states": [variable_dict(v) for v in plant.state_vars],
        "inputs": [variable_dict(v) for v in plant.input_vars],
        "outputs": [variable_dict(v) for v in plant.output_vars],
        "disturbances": [variable_dict(v) for v in plant.disturbance_vars],
        "operating_points": ops,
    }
