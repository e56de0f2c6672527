"""Property tests: every unit plant's rhs/outputs are finite with the right shapes
anywhere in a physically meaningful box (inputs within their actuator bounds)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim import get_plant

# (states box, inputs box, disturbances box); finite input bounds come from the plant
BOXES = {
    "cstr": ([(0.0, 1.2), (-2.0, 8.0)], [(-3.0, 3.0)], [(0.5, 1.5)]),
    "bioreactor": ([(0.0, 1.0), (0.0, 2.0)], [(0.0, 1.0)], [(1.0, 3.0)]),
    "two_phase_reactor": ([(1.0, 100.0)] * 3 + [(1.0, 29.0)], [(0.0, 100.0)] * 4, []),
    "calcium": ([(0.0, 0.33)] * 3 + [(0.01, 1.0), (1.0, 100.0)], [(0.0, 50.0)] * 2, []),
}


def vectors(box):
    return st.tuples(*[st.floats(lo, hi, allow_nan=False) for lo, hi in box]) if box \
        else st.just(())


@pytest.mark.parametrize("name", list(BOXES))
def test_rhs_and_outputs_finite_in_the_box(name):
    plant = get_plant(name)
    xs, us, ds = BOXES[name]
    for v, (lo, hi) in zip(plant.input_vars, us, strict=True):
        assert v.lower <= lo and hi <= v.upper  # the box respects actuator limits

    @settings(max_examples=150, deadline=None)
    @given(vectors(xs), vectors(us), vectors(ds))
    def check(x, u, d):
        x, u, d = (np.asarray(a, dtype=float) for a in (x, u, d))
        f = plant.rhs(0.0, x, u, d)
        y = plant.outputs(x, u)
        assert f.shape == (plant.nx,) and y.shape == (plant.ny,)
        assert np.all(np.isfinite(f)) and np.all(np.isfinite(y))

    check()


@pytest.mark.parametrize("name", list(BOXES))
def test_operating_points_inside_the_variable_bounds(name):
    plant = get_plant(name)
    for op in plant.operating_points.values():
        for value, var in zip(op.x, plant.state_vars, strict=True):
            assert var.lower <= value <= var.upper, (op.name, var.name)
        for value, var in zip(op.u, plant.input_vars, strict=True):
            assert var.lower <= value <= var.upper, (op.name, var.name)
        y = plant.outputs(op.x, op.u)
        for value, var in zip(y, plant.output_vars, strict=True):
            assert var.lower <= value <= var.upper, (op.name, var.name)
