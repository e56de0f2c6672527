"""The switching index fed with steady output errors (MultiModelSettings.index_errors)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.multimodel import HoldLaw, MultiModelController, MultiModelSettings
from controller.shared_basis import SharedBasis
from controller.state_shared import StateSharedModel
from controller.switching import IndexSettings

ROOTS = (-1.0, -2.0)  # omega(s) = (s + 1)(s + 2), omega(0) = 2
#: two models with the same DC gain 1 but poles of different speed: d(0) = 0.5 and 50
MODELS = {"slow": (-0.5, -1.0), "fast": (-5.0, -10.0)}
U_OP, Y_OP, OFFSET = 1.0, 3.0, 0.2


def _controller(index_errors, basis):
    specs = []
    for name, poles in MODELS.items():
        A = np.diag(poles)
        B = np.array([[1.0], [1.0]])
        C = np.array([[1.0, 1.0]]) / (-1.0 / poles[0] - 1.0 / poles[1])  # DC gain 1
        specs.append(StateSharedModel.model_from_linear(name, A, B, C, [U_OP], [Y_OP], basis))
    ssm = StateSharedModel(basis, 1, 0.05, specs)
    s = MultiModelSettings(index=IndexSettings(mu=1.0, nu=0.0, min_dwell=0.05),
                           index_errors=index_errors, y_hold="zoh")
    return MultiModelController(ssm, HoldLaw(), [U_OP], s, kinds=["fixed", "fixed"])


@pytest.mark.parametrize("basis", [SharedBasis.companion(np.poly(ROOTS)[1:][::-1]),
                                   SharedBasis.orthonormal(ROOTS)])
def test_steady_offset_weighs_every_model_alike(basis):
    # y held OFFSET above both models' steady value: the equation errors are the offset
    # times d_j(0)/omega(0) (0.25 and 25), the steady output errors the offset itself
    d0 = {name: np.prod(np.negative(p)) for name, p in MODELS.items()}
    for errors, expect in (("equation", [d0["slow"] / 2.0, d0["fast"] / 2.0]),
                           ("steady_output", [1.0, 1.0])):
        ctl = _controller(errors, basis)
        for k in range(400):
            dec = ctl.step(k, 0.05 * k, [Y_OP + OFFSET], [[Y_OP]])
        np.testing.assert_allclose(dec.J, (OFFSET * np.array(expect)) ** 2, rtol=1e-6)


def test_bad_index_errors_rejected():
    with pytest.raises(ValueError, match="index_errors"):
        MultiModelSettings(index_errors="output")
