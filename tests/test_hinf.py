"""Mixed-sensitivity H-infinity synthesis (seed §5.2) against python-control references."""

import control as ct
import numpy as np
import pytest

from controller.hinf import (
    HInfSynthesisError,
    HInfWeights,
    siso_model_tf,
    synthesize,
)

# Table 5.3 (CSTR, k1 (s + k2)/(s^2 + k3 s + k4)) and Table 5.10 OPII (bioreactor)
CSTR_OPI = ([0.3, 0.3 * 1.2440], [1.0, 1.1605, 0.2337])
CSTR_OPIII = ([0.3, 0.3 * 1.4437], [1.0, 0.7121, -0.1548])  # saddle, open-loop unstable
BIO_OPII = ([1.4110, 0.5654], [1.0, 0.9000, -0.1281])  # saddle, open-loop unstable
GAMMA_RTOL = 0.01  # bisection tolerance is 1e-3; mixsyn's own iteration is coarser
NORM_RTOL = 1e-3


@pytest.mark.parametrize("model", [CSTR_OPI, CSTR_OPIII])
def test_optimal_gamma_matches_python_control_mixsyn(model):
    w = HInfWeights.seed_cstr()
    design = synthesize(*model, w, dt=0.05)
    _, _, info = ct.mixsyn(ct.ss(ct.tf(*model)), w1=ct.ss(w.w1()), w2=ct.ss(w.w2()))
    assert design.gamma_opt == pytest.approx(info[0], rel=GAMMA_RTOL)
    # no controller beats |W1(inf)| = 1/2 for a strictly proper model
    assert design.gamma_opt >= 0.5


@pytest.mark.parametrize("model, weights", [(CSTR_OPI, HInfWeights.seed_cstr()),
                                            (CSTR_OPIII, HInfWeights.seed_cstr()),
                                            (BIO_OPII, HInfWeights.seed_bioreactor())])
def test_closed_loop_norm_is_below_gamma_and_loop_is_stable(model, weights):
    d = synthesize(*model, weights, dt=0.02)
    M = ct.tf(*model)
    S = ct.feedback(1, M * d.K_hinf)
    # [W1 S; W2 K S] as one single-input, two-output system
    CL = ct.append(ct.ss(weights.w1() * S), ct.ss(weights.w2() * d.K_hinf * S))
    stacked = ct.ss(CL.A, CL.B @ np.ones((2, 1)), CL.C, CL.D @ np.ones((2, 1)))
    assert ct.norm(stacked, p="inf") <= d.gamma * (1 + NORM_RTOL)
    assert np.all(d.closed_loop_poles.real < 0)
    assert d.max_discrete_pole < 1.0


def test_integral_action_removes_the_steady_offset():
    w = HInfWeights.seed_cstr()
    with_int = synthesize(*CSTR_OPI, w, dt=0.05)
    without = synthesize(*CSTR_OPI, HInfWeights.seed_cstr(integral=False), dt=0.05)
    M = ct.tf(*CSTR_OPI)
    s_int = abs(ct.evalfr(ct.feedback(1, M * with_int.K), 1e-7j))
    s_plain = abs(ct.evalfr(ct.feedback(1, M * without.K), 0))
    assert s_int < 1e-5
    # without the exchange the offset is the weight's |S(0)| ~ gamma 2 eps / a
    assert 1e-3 < s_plain < 0.1


def test_siso_model_tf_follows_eq_3_16():
    # theta1 = numerator coefficients, theta2 = a - d (lowest power first)
    a = [1.0, 1.0]
    num, den = siso_model_tf([0.3732, 0.3], [1.0 - 0.2337, 1.0 - 1.1605], a)
    np.testing.assert_allclose(num, [0.3, 0.3732])
    np.testing.assert_allclose(den, [1.0, 1.1605, 0.2337])


def test_zero_numerator_is_a_synthesis_error():
    with pytest.raises(HInfSynthesisError, match="numerator"):
        synthesize([0.0, 0.0], [1.0, 1.0, 1.0], HInfWeights.seed_cstr(), dt=0.05)


@pytest.mark.parametrize(
    "kwargs, field",
    [({"w1_den": (1.0, -1.0)}, "w1_den"), ({"w2_num": (1.0, 2.0, 3.0)}, "w2_num"),
     ({"gamma_factor": 0.5}, "gamma_factor"), ({"w1_num": (0.0, 1.0)}, "w1_num")],
)
def test_weights_name_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        HInfWeights(**kwargs)


def _ssm_with_adaptive(tf):
    from controller.state_shared import ModelSpec, StateSharedModel

    sys = ct.ss(ct.tf(*tf))
    spec = StateSharedModel.model_from_linear("M", np.asarray(sys.A), np.asarray(sys.B),
                                              np.asarray(sys.C), [0.4], [1.3], [1.0, 1.0])
    return StateSharedModel([1.0, 1.0], 1, 0.05,
                            [spec, ModelSpec("A", spec.theta, spec.bias, "adaptive")])


def test_hinf_law_resynthesizes_only_beyond_the_threshold():
    from controller.hinf import HInfLaw

    ssm = _ssm_with_adaptive(CSTR_OPI)
    law = HInfLaw(HInfWeights.seed_cstr(a=3.0), 0.05, resynthesis_threshold=0.1)
    law.reset([0.4], [1.3])
    y, r = np.array([1.3]), np.array([[1.3]])
    law.compute(0, 1, ssm, y, r, np.array([0.4]))
    assert law.n_syntheses == 1
    p = ssm.params_from_theta(ssm.theta(1), ssm.bias(1))
    ssm.set_params(1, p * 1.02)  # 2 % change: below the threshold, same controller
    law.compute(1, 1, ssm, y, r, np.array([0.4]))
    assert law.n_syntheses == 1
    ssm.set_params(1, p * 1.3)  # 30 % change: new synthesis
    u, info = law.compute(2, 1, ssm, y, r, np.array([0.4]))
    assert law.n_syntheses == 2 and info["status"] == "solved"
    # the change of controller is bumpless: zero error keeps the input
    assert u[0] == pytest.approx(0.4, abs=1e-12)
    law.compute(3, 0, ssm, y, r, np.array([0.4]))  # the fixed model gets its own
    assert law.n_syntheses == 3


def test_hinf_law_keeps_its_controller_when_synthesis_fails():
    from controller.hinf import HInfLaw

    ssm = _ssm_with_adaptive(CSTR_OPI)
    law = HInfLaw(HInfWeights.seed_cstr(a=3.0), 0.05)
    law.reset([0.4], [1.3])
    y, r = np.array([1.3]), np.array([[1.5]])
    law.compute(0, 1, ssm, y, r, np.array([0.4]))
    p = ssm.params_from_theta(ssm.theta(1), ssm.bias(1))
    p[:2] = 0.0  # numerator zero: no controller exists
    ssm.set_params(1, p)
    u, info = law.compute(1, 1, ssm, y, r, np.array([0.4]))
    assert law.n_synthesis_failures == 1 and np.isfinite(u[0])
    assert any("synthesis" in a for a in info["alarms"])
