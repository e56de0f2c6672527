"""Plant models, operating points and integrators (pure: no I/O, no controller).

Use :func:`get_plant` to build a plant by its registry name.
"""

from __future__ import annotations

import importlib

from plant_sim.base import OperatingPoint, PlantInputError, PlantModel, Variable

__all__ = ["PLANTS", "get_plant", "plant_names", "OperatingPoint", "PlantModel", "Variable",
           "PlantInputError"]

# Registry name -> "module:factory". Imported lazily so that importing plant_sim
# stays cheap (the TE port compiles with numba on first use).
PLANTS: dict[str, str] = {
    "cstr": "plant_sim.cstr:CSTR",
    "bioreactor": "plant_sim.bioreactor:Bioreactor",
    "two_phase_reactor": "plant_sim.two_phase_reactor:TwoPhaseReactor",
    "calcium": "plant_sim.calcium:Calcium",
    "te": "plant_sim.tennessee_eastman:TennesseeEastman",
}


def plant_names() -> list[str]:
    """Registry names of all plants."""
    return list(PLANTS)


def get_plant(name: str, **options) -> PlantModel:
    """Build the plant registered as ``name``.

    Raises
    ------
    PlantInputError
        For an unknown name (the message lists the known ones).
    """
    if name not in PLANTS:
        raise PlantInputError(f"plant: unknown plant {name!r}; known: {', '.join(PLANTS)}")
    module_name, factory = PLANTS[name].split(":")
    module = importlib.import_module(module_name)
    return getattr(module, factory)(**options)
