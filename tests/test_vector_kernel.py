"""The compiled QP vector assembly gives the numpy expression's vectors (eq. 6.10)."""

import numpy as np
import pytest

from controller.mpc import MPCSettings
from controller.mpc.formulation import build_formulation


def _model(rng, n, nu):
    Phi = rng.standard_normal((n, n))
    Phi *= 0.9 / max(abs(np.linalg.eigvals(Phi)))
    return Phi, rng.standard_normal((n, nu)), rng.standard_normal((nu, n))


def _settings(nu, *, soft: bool, target: bool, P=10, M=4):
    kw = {}
    if soft:
        kw = dict(y_max=np.r_[1.0, np.full(nu - 1, np.inf)], y_min=np.full(nu, -2.0),
                  slack_scale=np.full(nu, 0.5), slack_linear=1e3, slack_quadratic=10.0)
    if target:
        kw.update(u_target=np.full(nu, 0.3), u_target_weight=np.linspace(0.0, 1.0, nu))
    return MPCSettings(nu=nu, ny=nu, P=P, M=M, Xi=np.linspace(1.0, 3.0, nu),
                       Lambda=np.full(nu, 0.1), u_min=np.full(nu, -5.0),
                       u_max=np.r_[np.full(nu - 1, 5.0), np.inf], du_max=np.full(nu, 1.0),
                       **kw)


@pytest.mark.parametrize("soft", [True, False])
@pytest.mark.parametrize("target", [True, False])
@pytest.mark.parametrize("n, nu", [(6, 2), (80, 5)])
def test_kernel_vectors_equal_the_numpy_expression(soft, target, n, nu):
    rng = np.random.default_rng(n + 10 * soft + 100 * target)
    s = _settings(nu, soft=soft, target=target)
    form = build_formulation(*_model(rng, n, nu), s)
    for _ in range(5):
        x, x_prev = rng.standard_normal(n), rng.standard_normal(n)
        y, u_prev = rng.standard_normal(nu), rng.standard_normal(nu)
        R = rng.standard_normal((s.P, nu))
        u_target = rng.standard_normal(nu)
        x_a, got = form.sample_vectors(x, x_prev, y, u_prev, R, u_target)
        expected_xa = np.concatenate([x - x_prev, y])
        want = form.qp_vectors(expected_xa, u_prev, R, None, u_target)
        np.testing.assert_array_equal(x_a, expected_xa)
        for name in ("f", "lb", "ub", "bl", "bu"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), name)


def test_kernel_vectors_against_the_formula_written_out():
    """Independent of qp_vectors: f = F_x x_a - F_r r, input rows shifted by u(k-1),
    soft rows by S_x x_a."""
    rng = np.random.default_rng(3)
    s = _settings(2, soft=True, target=False, P=5, M=2)
    form = build_formulation(*_model(rng, 4, 2), s)
    x, x_prev, y, u_prev = (rng.standard_normal(k) for k in (4, 4, 2, 2))
    R = rng.standard_normal((5, 2))
    x_a, v = form.sample_vectors(x, x_prev, y, u_prev, R)
    np.testing.assert_allclose(v.f[:-1], form.F_x @ x_a - form.F_r @ R.ravel(), rtol=1e-13)
    assert v.f[-1] == s.slack_linear
    # input rows (each input has a finite limit: all M nu rows): [u_min, u_max] - u(k-1)
    n_in = form.input_rows.size
    assert n_in == 4
    np.testing.assert_array_equal(v.bl[:n_in], np.tile(s.u_min - u_prev, 2))
    np.testing.assert_array_equal(v.bu[:n_in], np.tile(s.u_max - u_prev, 2))
    assert np.isinf(v.bu[1]) and np.isinf(v.bu[3])  # input 2 has no upper limit
    Sx = form.S_x
    np.testing.assert_allclose(v.bu[n_in:n_in + form.ymax_rows.size],
                               np.tile(s.y_max, s.P)[form.ymax_rows]
                               - Sx[form.ymax_rows] @ x_a, rtol=1e-13)
    np.testing.assert_allclose(v.bl[n_in + form.ymax_rows.size:],
                               np.tile(s.y_min, s.P)[form.ymin_rows]
                               - Sx[form.ymin_rows] @ x_a, rtol=1e-13)


def test_stacked_bounds_check_and_order():
    from controller.mpc.vector_kernel import stacked_bounds

    f, lb, ub = np.array([1.0, 2.0]), np.array([-1.0, 0.0]), np.array([1.0, np.inf])
    bl, bu = np.array([-np.inf, -3.0]), np.array([4.0, 5.0])
    upper, lower = np.full(4, np.nan), np.full(4, np.nan)
    assert stacked_bounds(f, lb, ub, bl, bu, upper, lower)
    np.testing.assert_array_equal(upper, np.concatenate([ub, bu]))
    np.testing.assert_array_equal(lower, np.concatenate([lb, bl]))
    for name, arr, bad in (("f", f, np.inf), ("f", f, np.nan), ("lb", lb, np.nan),
                           ("bu", bu, np.nan)):
        changed = {"f": f, "lb": lb, "ub": ub, "bl": bl, "bu": bu}
        arr = arr.copy()
        arr[1] = bad
        changed[name] = arr
        assert not stacked_bounds(*changed.values(), upper, lower), name


def test_clip_move_equals_numpy_minimum_maximum():
    from controller.mpc.vector_kernel import clip_move

    rng = np.random.default_rng(9)
    for _ in range(500):
        nu = int(rng.integers(1, 7))
        du = rng.standard_normal(nu) * 3.0
        du_max = rng.uniform(0.1, 2.0, nu)
        u_prev = rng.standard_normal(nu) * 5.0
        u_min = np.where(rng.uniform(size=nu) < 0.2, -np.inf, -4.0)
        u_max = np.where(rng.uniform(size=nu) < 0.2, np.inf, 4.0)
        d, u = clip_move(du, du_max, u_prev, u_min, u_max)
        want_d = np.minimum(np.maximum(du, -du_max), du_max)
        np.testing.assert_array_equal(d, want_d)
        np.testing.assert_array_equal(u, np.minimum(np.maximum(u_prev + want_d, u_min), u_max))
