"""Tennessee Eastman port against the original Fortran program (te_reference/ and te.md).

Expected values come from the published Fortran build (reference files, numbers
printed in te.md), never from this code.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED, sequence

REF = Path("/work/shared/facts/te_reference")
pytestmark = pytest.mark.skipif(not REF.is_dir(), reason="reference files not available")

T0_RTOL = 1e-12  # t = 0 derivatives and XMEAS (issue: <= 1e-12 relative)
TRAJ_RTOL = 1e-9  # 1 h trajectory, column-scaled (issue: <= 1e-9)
STEP_H = 1.8 / 3600.0


def _load(name: str) -> np.ndarray:
    return np.loadtxt(REF / name, delimiter=",", skiprows=1)


def test_generator_first_five_values_of_original_seed():
    # te.md 7: the double-precision sequence, not the exact integer LCG
    expected = [1428579464, 266573016, 3126355528, 1446629400, 1140697608]
    np.testing.assert_array_equal(sequence(ORIGINAL_SEED, 5), expected)
    exact_lcg = (int(ORIGINAL_SEED) * 9228907) % 2**32
    assert exact_lcg != expected[0]  # the original departs from exact integers at once


def test_single_precision_literals_follow_the_fortran_rules():
    # te.md 10 examples
    assert C.literal_value("273.15") == 273.1499938964844
    assert C.literal_value("998.9") == 998.9000244140625
    assert C.literal_value("31.5859536") == 31.585952758789062
    assert C.literal_value("0.1") == 0.10000000149011612
    assert C.literal_value("40000.0/1.987") == 20130.8515625
    assert C.literal_value("0.767488334D0") == 0.767488334
    assert C.literal_value("273.15", "double") == 273.15
    assert C.literal_value("40000.0/1.987", "double") == 40000.0 / 1.987


def test_initial_state_derivatives_and_xmeas_at_t0():
    c = _load("c_deriv_t0.csv")
    d = _load("d_xmeas_t0.csv")
    sim = TESimulator()
    np.testing.assert_array_equal(sim.x, c[:, 1])
    # near-zero derivatives: absolute tolerance scaled by the state's magnitude
    atol = T0_RTOL * np.abs(c[:, 1])
    assert np.all(np.abs(sim.initial_derivative - c[:, 2]) <= T0_RTOL * np.abs(c[:, 2]) + atol)
    np.testing.assert_allclose(sim.initial_xmeas, d[:, 1], rtol=T0_RTOL, atol=0)


def test_base_xmv_are_the_float32_rounded_valve_states():
    sim = TESimulator()
    assert sim.xmv[0] == 63.05263137817383  # te.md 3


def test_one_hour_open_loop_trajectory_column_scaled():
    ref = _load("a_base_1h_nonoise_dt1.8s.csv")
    sim = TESimulator()
    rows = sim.run_steps(2001, record_every=20)
    assert rows.shape == ref.shape
    scale = np.max(np.abs(ref), axis=0)
    scale[scale == 0] = 1.0
    err = np.abs(rows - ref) / scale
    assert err.max() <= TRAJ_RTOL, f"worst at row/col {np.unravel_index(err.argmax(), err.shape)}"
    # time is accumulated, not recomputed (te.md 11)
    assert rows[1, 0] == 0.010000000000000005


def test_double_literal_build_differs_from_published_at_t0():
    c = _load("c_deriv_t0.csv")
    sim = TESimulator(literals="double")
    rel = np.abs(sim.initial_derivative - c[:, 2]) / (np.abs(c[:, 2]) + 1e-300)
    assert np.median(rel) > 1e-6


def test_step_by_step_equals_run_steps():
    a = TESimulator(noise=True)
    b = TESimulator(noise=True)
    rows = a.run_steps(300, record_every=1)
    for k in range(300):
        xm = b.step()
        np.testing.assert_array_equal(xm, rows[k, 1:42])
    np.testing.assert_array_equal(a.x, b.x)
    assert a.generator_state == b.generator_state


@settings(max_examples=300, deadline=None)
@given(st.integers(min_value=0, max_value=2**36))
def test_floor_form_of_generator_is_bit_identical_to_fmod(g):
    # te.md 7: the original computes DMOD(G*9228907, 2**32) in double precision
    expected = math.fmod(float(g) * 9228907.0, 4294967296.0)
    assert sequence(float(g), 1)[0] == expected
