"""Verisig 2.0 models whose network inputs include constants (ACC's ``_f1' := 30.0``, a set
speed): generated here in the format Verisig writes, they load as the same loop as the model that
spells the constant ``30.0 + 0 * x`` (which the reader always took), their float runs match a
plain numpy simulation with the constant fed to the network, and they verify alike."""

import numpy as np
from scipy.integrate import solve_ivp

import percver as pv

# A 1-D car: x' = v, v' = u - 0.1 v, u = net(v_set, x, v); the network is fed the constant set
# speed through _f1 and the states through _f2, _f3. Unsafe: x >= 4.
MODEL = """hybrid reachability
{{
    state var _f1, _f2, _f3, x, v, u, clock

    setting
    {{
        adaptive steps {{min 1e-6, max 0.01}}
        time 2
        remainder estimation 1e-2
        identity precondition
        gnuplot octagon x, v
        fixed orders 4
        cutoff 1e-10
        precision 100
        output car
        max jumps 100
        print on
    }}

    modes
    {{
        m0 {{ nonpoly ode {{ x' = 0 v' = 0 u' = 0 _f1' = 0 _f2' = 0 _f3' = 0 clock' = 1 }} inv {{ clock <= 0 }} }}
        DNNm1 {{ nonpoly ode {{ x' = 0 v' = 0 u' = 0 _f1' = 0 _f2' = 0 _f3' = 0 clock' = 1 }} inv {{ clock <= 0 }} }}
        _cont_sys {{ nonpoly ode {{ x' = v v' = u - 0.1 * v u' = 0 _f1' = 0 _f2' = 0 _f3' = 0 clock' = 1 }} inv {{ clock <= 0.1 }} }}
        startmode {{ nonpoly ode {{ x' = 0 v' = 0 u' = 0 _f1' = 0 _f2' = 0 _f3' = 0 clock' = 1 }} inv {{ clock <= 0 }} }}
        unsafe1 {{ nonpoly ode {{ x' = 0 v' = 0 u' = 0 _f1' = 0 _f2' = 0 _f3' = 0 clock' = 1 }} inv {{ clock <= 1 }} }}
    }}

    jumps
    {{
        m0 -> DNNm1
        guard {{ }}
        reset {{ clock' := 0 }}
        interval aggregation
        DNNm1 -> _cont_sys
        guard {{ }}
        reset {{ u' := _f1 clock' := 0 }}
        interval aggregation
        _cont_sys -> unsafe1
        guard {{ x >= 4 }}
        reset {{ clock' := 0 }}
        interval aggregation
        _cont_sys -> m0
        guard {{ clock = 0.1 }}
        reset {{ _f1' := {set_speed} _f2' := x _f3' := v clock' := 0 }}
        interval aggregation
        startmode -> m0
        guard {{ clock = 0 }}
        reset {{ _f1' := {set_speed} _f2' := x _f3' := v clock' := 0 }}
        interval aggregation
    }}

    init
    {{
        startmode
        {{
            x in [0, 0.1]
            v in [0.9, 1]
            u in [0, 0]
            _f1 in [0, 0]
            _f2 in [0, 0]
            _f3 in [0, 0]
            clock in [0, 0]
        }}
    }}
}}

unsafe
{{
    unsafe1 {{ x >= 4 }}
}}
"""

SET_SPEED = 1.5
W1 = np.array([[0.4, -0.3, -0.5], [0.2, 0.1, -0.6]])
B1 = np.array([0.05, -0.1])
W2 = np.array([[0.8, 0.7]])
B2 = np.array([0.0])


def write(tmp_path, name, set_speed):
    net = pv.Network([(W1, B1, "tanh"), (W2, B2, "identity")], name="car")
    pv.save_network(net, tmp_path / "car.yml")
    (tmp_path / name).write_text(MODEL.format(set_speed=set_speed))
    return pv.load_verisig(str(tmp_path / name), networks=[str(tmp_path / "car.yml")])


def numpy_runs(x0, steps):
    """The model by hand: the network's weights in numpy, the constant set speed as its first input."""
    out = [x0]
    x = np.array(x0, float)
    for _ in range(steps):
        u = (W2 @ np.tanh(W1 @ np.stack([np.full(len(x), SET_SPEED), x[:, 0], x[:, 1]]) + B1[:, None]) + B2[:, None])[0]
        for i in range(len(x)):
            sol = solve_ivp(lambda _t, s: [s[1], u[i] - 0.1 * s[1]], (0, 0.1), x[i], rtol=1e-11, atol=1e-12)
            x[i] = sol.y[:, -1]
        out.append(x.copy())
    return np.stack(out, axis=1)


def test_a_constant_reset_is_a_network_input(tmp_path):
    constant = write(tmp_path, "constant.model", f"{SET_SPEED}")
    spelled = write(tmp_path, "spelled.model", f"{SET_SPEED} + 0 * x")
    assert constant.states == spelled.states == ["x", "v"] and constant.steps == spelled.steps == 20
    x0 = pv.Box.coerce({"x": (0, 0.1), "v": (0.9, 1)}).sample(12, seed=1)
    runs = constant.simulate(x0, 20)
    np.testing.assert_allclose(runs, spelled.simulate(x0, 20), rtol=0, atol=1e-12)
    np.testing.assert_allclose(runs, numpy_runs(x0, 20), rtol=1e-8, atol=1e-8)
    a, b = (pv.verify(p, progress=False) for p in (constant, spelled))
    assert a.verdict == b.verdict
    assert a.verdict == ("verified" if runs[:, :, 0].max() < 4 else "falsified")
    np.testing.assert_allclose(a.cells[0].boxes, b.cells[0].boxes, rtol=0, atol=1e-9)
    # Every simulated run lies in the reach boxes of the verified cell.
    boxes = np.asarray(a.cells[0].boxes)
    assert np.all((runs >= boxes[None, :, :, 0] - 1e-12) & (runs <= boxes[None, :, :, 1] + 1e-12))
