"""Stage and plant inputs: constants fed to a network (ACC's v_set = 30, T_gap = 1.4), and a
network with a vector output driving a continuous plant (inputs=["T"] read as T_0, T_1, or the
components declared). Each loop is checked against a numpy simulation of its own weights, and
the reach boxes of its verified cell against sampled runs."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv

x, v = pv.variables("x v")
W1, B1 = np.array([[0.5, -0.3, 0.2, 0.4], [0.1, 0.2, -0.6, 0.3]]), np.array([0.1, -0.2])
W2, B2 = np.array([[0.7, -0.4]]), np.array([0.05])
V_SET, T_GAP = 1.5, 1.4


def controller(x_, v_):
    """The ACC-style controller by hand: u = W2 tanh(W1 [v_set, t_gap, x, v] + B1) + B2."""
    z = np.stack([np.full_like(x_, V_SET), np.full_like(x_, T_GAP), x_, v_])
    return (W2 @ np.tanh(W1 @ z + B1[:, None]) + B2[:, None])[0]


def numpy_runs(x0, steps, rhs, control):
    out, state = [x0.copy()], x0.copy()
    for _ in range(steps):
        u = control(state[:, 0], state[:, 1])
        for i in range(len(state)):
            state[i] = solve_ivp(lambda _t, s: rhs(s, u[..., i]), (0, 0.1), state[i], rtol=1e-11, atol=1e-12).y[:, -1]
        out.append(state.copy())
    return np.stack(out, axis=1)


def inside(res, runs):
    boxes = np.asarray(res.cells[0].boxes)
    assert len(boxes) == runs.shape[1]
    tol = 1e-9  # the float integrator's error
    return np.all((runs >= boxes[None, :, :, 0] - tol) & (runs <= boxes[None, :, :, 1] + tol))


INIT = {"x": (0, 0.1), "v": (0.9, 1)}


def test_constant_network_inputs():
    net = pv.Network([(W1, B1, "tanh"), (W2, B2, "identity")])
    plant = pv.Continuous({x: v, v: pv.parse("u") - 0.1 * v}, inputs=["u"], period=0.1)
    loop = pv.ClosedLoop(plant, [pv.Stage(net, inputs=[V_SET, T_GAP, x, v], output="u")])
    x0 = pv.Box(INIT).sample(20, seed=4)
    runs = numpy_runs(x0, 10, lambda s, u: [s[1], u - 0.1 * s[1]], controller)
    np.testing.assert_allclose(loop.simulate(x0, 10), runs, rtol=1e-8, atol=1e-9)
    res = pv.verify(loop, init=INIT, steps=10, safe=x <= 5, progress=False)
    assert res.verdict == "verified" and inside(res, runs)
    # The same constant twice shares one signal; a constant in an expression stage is refused.
    twice = pv.ClosedLoop(plant, [pv.Stage(net, inputs=[V_SET, V_SET, x, v], output="u")])
    assert twice.env_names == ["x", "v", "_constants", "u"]
    with pytest.raises(pv.InputError, match="constant inputs \\[2.0\\] feed networks"):
        pv.Stage(x + 1, inputs=[x, 2.0], output="y")
    with pytest.raises(pv.InputError, match="takes 4 inputs but is wired to 1.5 \\(1\\) \\+ x \\(1\\) = 2"):
        pv.ClosedLoop(plant, [pv.Stage(net, inputs=[V_SET, x], output="u")])


def vector_net():
    return pv.Network([(W1[:, 2:], B1, "tanh")])  # (x, v) -> T = (T_0, T_1)


@pytest.mark.parametrize("inputs", [["T"], ["T_0", "T_1"]])
def test_a_vector_output_drives_a_continuous_plant(inputs):
    t0, t1 = pv.variables("T_0 T_1")
    plant = pv.Continuous({x: v + 0.1 * t0, v: t1 - 0.1 * v}, inputs=inputs, period=0.1)
    loop = pv.ClosedLoop(plant, [pv.Stage(vector_net(), inputs=[x, v], output="T")])
    assert loop.plant_inputs == ["T_0", "T_1"]
    x0 = pv.Box(INIT).sample(20, seed=5)

    def control(x_, v_):
        return np.tanh(W1[:, 2:] @ np.stack([x_, v_]) + B1[:, None])

    runs = numpy_runs(x0, 10, lambda s, u: [s[1] + 0.1 * u[0], u[1] - 0.1 * s[1]], control)
    np.testing.assert_allclose(loop.simulate(x0, 10), runs, rtol=1e-8, atol=1e-9)
    res = pv.verify(loop, init=INIT, steps=10, safe=x <= 5, progress=False)
    assert res.verdict == "verified" and inside(res, runs)


def test_vector_inputs_refused_clearly():
    t0 = pv.Expr.var("T_0")
    stage = pv.Stage(vector_net(), inputs=[x, v], output="T")
    with pytest.raises(pv.InputError, match="not produced by any stage"):
        pv.ClosedLoop(pv.Continuous({x: v, v: t0}, inputs=["T_2"], period=0.1), [stage])
    with pytest.raises(pv.InputError, match="'T' is a vector of 2: use its components T_0 .. T_1"):
        pv.ClosedLoop(pv.Continuous({x: v, v: pv.parse("T")}, inputs=["T_0"], period=0.1), [stage])
    with pytest.raises(pv.InputError, match="neither states nor its declared inputs"):
        pv.ClosedLoop(pv.Continuous({x: v, v: pv.parse("T_1")}, inputs=["T_0"], period=0.1), [stage])
