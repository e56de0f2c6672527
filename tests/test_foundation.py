"""The shared records: plant variable lookup and benchmark summaries."""

import numpy as np
import pytest

from plant_sim import PlantInputError, get_plant
from services.bench._common import latency_case, rate_case


def test_variables_by_kind_and_clear_errors():
    plant = get_plant("cstr")
    assert plant.names("output") == [v.name for v in plant.output_vars]
    assert plant.index("input", plant.input_vars[0].name) == 0
    with pytest.raises(PlantInputError, match="kind"):
        plant.variables("parameter")
    with pytest.raises(PlantInputError, match="nosuch"):
        plant.index("state", "nosuch")


def test_latency_case_tail_is_the_slow_end():
    samples = np.arange(1.0, 101.0)  # 1..100 us
    case = latency_case("x", samples)
    assert case["median"] == pytest.approx(50.5)
    assert case["p99"] == pytest.approx(np.percentile(samples, 99))
    assert case["max"] == 100.0 and case["n"] == 100


def test_rate_case_tail_is_the_slow_end():
    rates = np.arange(1.0, 101.0)  # higher is better
    case = rate_case("x", rates, "sim-h/s")
    assert case["p99"] == pytest.approx(np.percentile(rates, 1))
    assert case["p99"] < case["median"] < case["max"]


def test_empty_samples_rejected():
    with pytest.raises(ValueError, match="no samples"):
        latency_case("x", [])
