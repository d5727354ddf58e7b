"""pv.Perception: the paper's roles by name, as the stages of a closed loop."""

import numpy as np
import pytest

import percver as pv


def _roles():
    x, v, y, n, d, e, u = pv.variables("x v y noisy delta x_hat u")
    return dict(
        canonical=pv.Stage([2.0 * x], inputs=[x], output="y"),
        noiser=pv.Stage([y + 0.1 * d], inputs=[y, d], output="noisy"),
        estimator=pv.Stage([0.5 * n], inputs=[n], output="x_hat"),
        controller=pv.Stage([-0.3 * e - 0.1 * v], inputs=[e, v], output="u"),
    ), pv.Discrete({x: x + 0.1 * v, v: v + 0.1 * u, d: d}, inputs=["u"])


def test_the_loop_of_a_perception_is_the_loop_of_its_stages_in_role_order():
    roles, plant = _roles()
    named = pv.ClosedLoop(plant, pv.Perception(**roles))
    listed = pv.ClosedLoop(plant, [roles["canonical"], roles["noiser"], roles["estimator"], roles["controller"]])
    assert [s.output for s in named.stages] == ["y", "noisy", "x_hat", "u"]
    x0 = [[-0.4, 0.2, 0.7], [0.3, -0.1, -1.0]]  # x, v, delta
    np.testing.assert_array_equal(named.simulate(x0, 20), listed.simulate(x0, 20))
    init = {"x": (-0.5, -0.4), "v": (0.0, 0.1), "delta": (-1.0, 1.0)}
    a = pv.verify(named, init, steps=10, safe=[pv.Expr.var("x") <= 1.0], progress=False)
    b = pv.verify(listed, init, steps=10, safe=[pv.Expr.var("x") <= 1.0], progress=False)
    assert a.verdict == b.verdict == "verified"
    assert pv.Perception(**roles).role("x_hat") == "estimator"


def test_a_role_that_reads_a_later_role_is_refused_by_name():
    roles, _ = _roles()
    swapped = dict(roles, estimator=roles["controller"], controller=roles["estimator"])
    with pytest.raises(pv.InputError, match="estimator reads 'x_hat', which the controller writes later"):
        pv.Perception(**swapped)


def test_a_role_must_be_a_stage():
    roles, _ = _roles()
    with pytest.raises(pv.InputError, match="denoiser must be a pv.Stage, got list"):
        pv.Perception(**roles, denoiser=[roles["noiser"]])
