"""Unit registry and the PI baseline against independent references."""

import json

import numpy as np
import pytest

from controller.units.baselines import PIBaseline
from controller.units.config import UnitConfig
from services.registry import build_controller, get_unit, load_unit_config

# Seed Table 5.3 (facts/cstr_bioreactor.md): G(s) = k1 (s + k2) / (s^2 + k3 s + k4) at OPI
K1, K2, K4 = 0.3000, 1.2440, 0.2337
TABLE_TOL = 2e-3  # the table prints 4 decimals


def test_pi_gain_uses_the_cstr_steady_state_gain_of_table_5_3():
    from dataclasses import replace

    cfg = replace(get_unit("cstr"), controller="pi")
    ctrl = build_controller(cfg)
    g0 = K1 * K2 / K4
    assert ctrl.K[0, 0] == pytest.approx(cfg.pi_gain / g0, rel=TABLE_TOL)


def test_velocity_form_equals_positional_pi_without_saturation():
    K, Ts, Ti = 0.7, 0.1, 2.0
    pi = PIBaseline([[K]], Ts, Ti, u0=[0.5])
    rng = np.random.default_rng(1)
    errors = rng.normal(size=50)
    for k, e in enumerate(errors):
        d = pi.step(k, k * Ts, [0.0], [[e]])  # r - y = e
        # positional form with e_{-1} = e_0 (no kick at the first sample)
        expected = 0.5 + K * (e - errors[0]) + K * Ts / Ti * errors[: k + 1].sum()
        assert d.u[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_saturation_and_invalid_measurement_hold():
    pi = PIBaseline([[10.0]], 1.0, 1.0, u0=[0.0], u_min=[-1.0], u_max=[1.0])
    assert pi.step(0, 0.0, [0.0], [[5.0]]).u[0] == 1.0
    d = pi.step(1, 1.0, [float("nan")], [[5.0]])
    assert d.fallback and d.status == "invalid_measurement" and d.u[0] == 1.0
    d = pi.step(2, 2.0, [0.0, 1.0], [[5.0]])
    assert d.fallback


def test_checkpoint_restore_continues_identically():
    a = PIBaseline([[0.5]], 0.1, 1.0, u0=[0.2])
    for k in range(5):
        a.step(k, 0.0, [0.0], [[1.0 + k]])
    b = PIBaseline([[0.5]], 0.1, 1.0, u0=[0.0])
    b.restore(json.loads(json.dumps(a.checkpoint())))
    for k in range(5, 10):
        assert a.step(k, 0.0, [0.1 * k], [[1.0]]).u[0] == b.step(k, 0.0, [0.1 * k], [[1.0]]).u[0]


@pytest.mark.parametrize("over, field", [
    ({"sample_period_s": 0}, "sample_period_s"),
    ({"budget_fraction": 2.0}, "budget_fraction"),
    ({"controller": "magic"}, "controller"),
    ({"plant": "nope"}, "plant"),
    ({"unit": "a/b"}, "unit"),
    ({"checkpoint_every": 0}, "checkpoint_every"),
])
def test_unit_config_validation_names_field(over, field):
    base = get_unit("cstr").as_dict()
    base.update(over)
    with pytest.raises(ValueError, match=field):
        UnitConfig(**base)


def test_unit_config_file_overrides(tmp_path):
    f = tmp_path / "u.json"
    f.write_text(json.dumps({"budget_fraction": 0.25, "initial_grade": "OPII"}))
    cfg = load_unit_config("cstr", f)
    assert cfg.budget_fraction == 0.25 and cfg.initial_grade == "OPII"
    f.write_text(json.dumps({"bogus": 1}))
    with pytest.raises(ValueError, match="bogus"):
        load_unit_config("cstr", f)
    with pytest.raises(ValueError, match="unit"):
        get_unit("nope")
