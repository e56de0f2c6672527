"""Seed chapter 5 through ``ssmpc reproduce R5.x --json``, against the catalogue's checks
(facts/seed_results.md R5.3-R5.13)."""

import contextlib
import functools
import io
import json

import pytest

from services.cli import main

CSTR_BAND = 0.02  # ±2 % of the target (R5.5, R5.7, R5.8)


@functools.cache
def _run(rid, *extra):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["reproduce", rid, "--json", *extra])
    return code, buf.getvalue().strip().splitlines()[-1]


def _reproduce(rid, capsys, *extra):
    """One CLI run per id (cached across tests); returns (document, rows by name)."""
    code, out = _run(rid, *extra)
    assert code == 0
    doc = json.loads(out)
    assert doc["id"] == rid and set(doc) == {"id", "rows", "verdict", "why", "figures"}
    return doc, {r["name"]: r for r in doc["rows"]}


def test_r4_1_convergence_small_error_and_bumpless_switching(capsys):
    doc, rows = _reproduce("R4.1", capsys)
    assert rows["in-class plant: max relative error of theta (PE)"]["ours"] <= 0.01
    assert rows["in-class plant: |e| over the last 200 samples / output range"]["ours"] <= 1e-3
    assert rows["switches in the R5.5 1.3 -> 5.0 run"]["ours"] >= 1
    assert (rows["largest jump of the active model's estimate at a switch"]["ours"]
            <= rows["largest one-sample change of y"]["ours"])


def test_r4_1_first_order_hold_identifies_the_continuous_theta(capsys):
    doc, rows = _reproduce("R4.1", capsys)
    row = rows["continuous plant, first-order hold of y: max relative error of theta"]
    assert row["ours"] <= 0.01  # R4.1: within 1 % of the true (continuous) Theta
    assert doc["verdict"] == "reproduced"


def test_r5_3_mrac_reaches_5_with_final_model_m2_or_m4(capsys, tmp_path):
    doc, rows = _reproduce("R5.3", capsys, "--plot", str(tmp_path))
    assert rows["MRAC 1.3->5.0: final |y - target|"]["ours"] <= 0.05
    assert rows["MRAC 1.3->5.0: final model (1-4)"]["ours"] in (2.0, 4.0)
    assert doc["verdict"] == "reproduced"
    assert doc["figures"] and all((tmp_path / p.split("/")[-1]).exists() for p in doc["figures"])


def test_r5_4_fixed_rows_match_table_5_4_exactly(capsys):
    doc, rows = _reproduce("R5.4", capsys)
    for name in ("M1", "M2"):
        for i in range(1, 5):
            r = rows[f"{name} k{i} (MRAC parametric model)"]
            assert r["ours"] == pytest.approx(r["seed"], abs=2e-3)  # printed to 4 decimals


def test_r5_5_hinf_both_directions_settle_within_2_percent(capsys):
    doc, rows = _reproduce("R5.5", capsys)
    assert rows["1.3->5.0: final |y - target|"]["ours"] <= CSTR_BAND * 5.0
    assert rows["5.0->1.3: final |y - target|"]["ours"] <= CSTR_BAND * 1.3
    assert rows["1.3->5.0: settling time (band 0.1)"]["ours"] <= 30.0
    assert rows["5.0->1.3: settling time (band 0.026)"]["ours"] <= 30.0
    assert doc["verdict"] == "reproduced"


def test_r5_6_reinitialized_model_ends_within_2_percent_of_m2(capsys):
    doc, rows = _reproduce("R5.6", capsys)
    assert rows["max relative |M4 - M2|"]["ours"] <= 0.02
    for i in range(1, 5):  # fixed rows are Table 5.3's linearizations (±2 %, R5.2)
        r = rows[f"M2 k{i}"]
        assert r["ours"] == pytest.approx(r["seed"], rel=0.02)


def test_r5_7_robustness_cases_stay_stable_and_settle(capsys):
    doc, rows = _reproduce("R5.7", capsys)
    finals = [r for name, r in rows.items() if name.endswith("final |y - target|")]
    assert len(finals) == 3
    targets = (5.0, 1.3, 5.0)
    for r, target in zip(finals, targets):
        assert r["ours"] <= CSTR_BAND * target
    assert doc["verdict"] == "reproduced"


def test_r5_8_every_leg_settles(capsys):
    doc, rows = _reproduce("R5.8", capsys)
    for target in ("2", "5", "1.3"):
        assert rows[f"leg -> {target}: settling time"]["ours"] is not None
    assert rows["M4 max relative deviation from M1"]["ours"] <= 0.05


def test_r5_8_free_running_model_fits_the_final_steady_state(capsys):
    doc, rows = _reproduce("R5.8", capsys)
    y_end = rows["measured y at the end"]["ours"]
    assert rows["M3 steady output at the final input"]["ours"] == pytest.approx(
        y_end, rel=CSTR_BAND)


@pytest.mark.xfail(reason="known gap: our free-running model ends far from M1 after the "
                          "1.3 -> 2 -> 5 -> 1.3 run (seed: close to M1): the last leg does not "
                          "excite its parameters apart; see R5.8 why", strict=True)
def test_r5_8_free_running_model_ends_close_to_m1(capsys):
    doc, rows = _reproduce("R5.8", capsys)
    assert rows["M3 max relative deviation from M1"]["ours"] <= 0.05


def test_r5_10_bioreactor_both_directions_within_0_01(capsys):
    doc, rows = _reproduce("R5.10", capsys)
    assert rows["OPI->OPII: final |y - target|"]["ours"] <= 0.01
    assert rows["OPII->OPI: final |y - target|"]["ours"] <= 0.01
    assert doc["verdict"] == "reproduced"


def test_r5_11_model_error_within_0_02(capsys):
    doc, rows = _reproduce("R5.11", capsys)
    assert rows["OPI->OPII: final |y - target|"]["ours"] <= 0.02
    assert rows["OPII->OPI: final |y - target|"]["ours"] <= 0.02


def test_r5_12_state_shared_beats_the_single_model_on_the_down_staircase(capsys):
    doc, rows = _reproduce("R5.12", capsys)
    assert rows["down (steps): ISE state-shared"]["ours"] < rows[
        "down (steps): ISE single model (OPII)"]["ours"]
    for label, target in (("up", 5.0), ("down", 1.3)):
        assert rows[f"{label} (steps): final |y - target| state-shared"]["ours"] <= (
            CSTR_BAND * target)


def test_r5_12_local_designs_at_every_level_do_not_beat_the_opi_design(capsys):
    """The evidence behind R5.12's verdict: even a fixed linearization (with its own design)
    at every staircase level tracks the up staircase worse than the OPI design alone."""
    doc, rows = _reproduce("R5.12", capsys)
    assert rows["up (steps): ISE fixed models at all 5 levels (no adaptation)"]["ours"] > rows[
        "up (steps): ISE single model (OPI)"]["ours"]


@pytest.mark.xfail(reason="known gap: the H-inf design on the OPI model alone is robust over the "
                          "whole range and beats the switched set on the up staircase; see R5.12 "
                          "why", strict=True)
def test_r5_12_state_shared_beats_single_model_on_the_up_staircase(capsys):
    doc, rows = _reproduce("R5.12", capsys)
    assert rows["up (steps): ISE state-shared"]["ours"] < rows[
        "up (steps): ISE single model (OPI)"]["ours"]


def test_r5_13_state_shared_stays_bounded_on_pulses(capsys):
    doc, rows = _reproduce("R5.13", capsys)
    assert rows["state-shared: bounded (1 = yes)"]["ours"] == 1.0
    assert rows["state-shared: final cell density x1"]["ours"] > 0.01


def test_r5_13_opi_design_stabilizes_the_unstable_opii_linearization(capsys):
    doc, rows = _reproduce("R5.13", capsys)
    assert rows["OPI-designed H-inf loop with the OPII linearization: max Re(pole)"]["ours"] < 0
    assert rows["OPI-designed H-inf loop over the steady-state curve x2 = 0.002-1.3 g/L: "
                "largest max Re(pole)"]["ours"] < 0


def test_sampled_opi_controller_with_the_exact_zoh_opii_linearization_is_stable():
    """Independent of the study's continuous pole computation: the implemented discrete
    controller against the OPII linearization sampled by a matrix exponential."""
    import numpy as np
    import scipy.linalg

    from controller.hinf import siso_model_tf, synthesize
    from plant_sim import get_plant
    from plant_sim.linearize import linearize
    from services.reproduce.ch5 import A_POLY, BIO_WEIGHTS, _fixed_spec

    plant = get_plant("bioreactor")
    th = _fixed_spec(plant, "OPI", "M1").theta[:, 0]
    ctrl = synthesize(*siso_model_tf(th[:2], th[2:], A_POLY), BIO_WEIGHTS, 0.02).discrete
    lin = linearize(plant, "OPII")
    assert np.max(np.linalg.eigvals(lin.A).real) > 0  # open-loop unstable
    E = scipy.linalg.expm(np.block([[lin.A, lin.B], [np.zeros((1, 3))]]) * 0.02)
    Ap, Bp, Cp = E[:2, :2], E[:2, 2:], lin.C
    loop = np.block([[Ap - Bp @ ctrl.D @ Cp, Bp @ ctrl.C], [-ctrl.B @ Cp, ctrl.A]])
    assert np.max(np.abs(np.linalg.eigvals(loop))) < 1.0


def test_r5_13_single_model_leaves_the_valid_region_and_state_shared_tracks(capsys):
    """Fig. 5.22 / seed_results R5.13: on the square pulses the single-model loop leaves the
    physical range on at least one pulse; the state-shared loop stays in it and tracks."""
    doc, rows = _reproduce("R5.13", capsys)
    assert rows["single model: bounded (1 = yes)"]["ours"] == 0.0
    left = rows["single model: leaves x2 >= 0 at t"]["ours"]
    assert left is not None and 2.0 < left < 30.0  # during the pulses (first at t = 2 h)
    assert rows["state-shared: bounded (1 = yes)"]["ours"] == 1.0
    assert rows["state-shared: y range min"]["ours"] >= 0.0
    amplitude = 0.389 - 0.0036  # g/L, OPI -> OPII (facts §2.3)
    assert rows["state-shared: max |y - r| at the plateau ends after the first pulse"][
        "ours"] <= 0.05 * amplitude
    assert doc["verdict"] == "reproduced"


def test_r5_13_no_loop_leaves_the_physical_range_with_nonnegative_dilution(capsys):
    """With D >= 0 the range 0 <= x2 <= x2f is invariant (dx2/dt = D x2f >= 0 at x2 = 0):
    the limited-input runs must all stay in it, whatever the controller does."""
    doc, rows = _reproduce("R5.13", capsys)
    for label in ("state-shared", "single model", "single model (OPII)"):
        assert rows[f"0 <= D <= 1: {label}: bounded (1 = yes)"]["ours"] == 1.0


# -- R5.1, R5.2, R5.9: steady states and linear models (printed numbers of Tables 5.3, 5.10)
TABLE_5_3 = {"OPI": (0.3000, 1.2440, 1.1605, 0.2337),
             "OPII": (0.3000, 4.9310, 2.1493, 2.3286),
             "OPIII": (0.3000, 1.4437, 0.7121, -0.1548)}
K_REL = 0.02  # catalogue: our linearizations reproduce k1-k4 within ±2 %


def test_r5_1_three_steady_states_two_stable_one_saddle(capsys):
    doc, rows = _reproduce("R5.1", capsys)
    for op in ("OPI", "OPII"):
        assert rows[f"steady states at {op}'s u (Fig. 5.2: three)"]["ours"] == 3
        assert rows[f"stable steady states at {op}'s u (Fig. 5.2: two nodes)"]["ours"] == 2
        assert rows[f"saddles at {op}'s u (Fig. 5.2: one)"]["ours"] == 1
    # OPI's u also has a steady state near OPII's y = 5.0 (the two outer branches)
    assert rows["steady state 3 at OPI's u: y"]["ours"] == pytest.approx(5.0, abs=0.05)
    assert doc["verdict"] == "reproduced"


def test_r5_2_linearizations_match_table_5_3(capsys):
    doc, rows = _reproduce("R5.2", capsys)
    for op, ks in TABLE_5_3.items():
        for i, k in enumerate(ks):
            row = rows[f"{op} k{i + 1}"]
            assert row["seed"] == k
            assert row["ours"] == pytest.approx(k, rel=K_REL)
    assert rows["OPIII eigenvalues in the right half-plane (printed type)"]["ours"] == 1
    assert rows["OPI eigenvalues in the right half-plane (printed type)"]["ours"] == 0
    # derived in the catalogue from the printed table: saddle pole +0.1746
    assert rows["OPIII pole 2, real part"]["ours"] == pytest.approx(0.1746, rel=K_REL)
    assert doc["verdict"] == "reproduced"


def test_r5_9_bioreactor_table_5_10_is_calibrated(capsys):
    doc, rows = _reproduce("R5.9", capsys)
    assert rows["OPII steady state x2"]["ours"] == pytest.approx(0.3890, abs=5e-4)
    assert rows["OPI steady state x1"]["ours"] == pytest.approx(0.6790, abs=5e-4)
    assert rows["OPI steady state x2"]["seed"] == 0.0003  # as printed (flagged)
    assert 0.003 <= rows["OPI steady state x2"]["ours"] <= 0.004  # the printed numerator's
    for name, v in (("OPI denominator s coefficient", 46.9331),
                    ("OPI denominator constant", 17.7229),
                    ("OPII denominator s coefficient", 0.9000),
                    ("OPII denominator constant", -0.1281),
                    ("OPII numerator s coefficient", 1.4110),
                    ("OPII numerator constant", 0.5654)):
        assert rows[name]["ours"] == pytest.approx(v, rel=K_REL)
    assert rows["OPII eigenvalues in the right half-plane (printed type)"]["ours"] == 1
    # the kinetics were fitted to this table: the verdict says so
    assert doc["verdict"] == "calibrated" and "fitted" in doc["why"]
