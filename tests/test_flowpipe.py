"""Flowpipes must contain every simulated trajectory: 1,000 initial points per system,
integrated by scipy (DOP853, rtol = atol = 1e-12) as one vectorised ODE, checked against the
box of every step at the step's ends and interior points."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv

# (name, variables, right-hand sides in Flow* syntax, numpy rhs, init box, t_end, order, step)
SYSTEMS = [
    (
        "vanderpol",
        "x y",
        ["y", "(1 - x^2)*y - x"],
        lambda x, y: (y, (1 - x * x) * y - x),
        {"x": (1.25, 1.55), "y": (2.28, 2.32)},
        7.0,
        6,
        0.02,
    ),
    (
        "brusselator",
        "x y",
        ["1 + x^2*y - 2.5*x", "1.5*x - x^2*y"],
        lambda x, y: (1 + x * x * y - 2.5 * x, 1.5 * x - x * x * y),
        {"x": (0.8, 1.0), "y": (0.0, 0.2)},
        5.0,
        6,
        0.02,
    ),
    (
        "lotka_volterra",
        "x y",
        ["1.5*x - x*y", "-3*y + x*y"],
        lambda x, y: (1.5 * x - x * y, -3 * y + x * y),
        {"x": (4.8, 5.2), "y": (1.8, 2.2)},
        3.0,
        6,
        0.01,
    ),
    (
        "jet_engine",
        "x y",
        ["-y - 1.5*x^2 - 0.5*x^3 - 0.5", "3*x - y"],
        lambda x, y: (-y - 1.5 * x * x - 0.5 * x**3 - 0.5, 3 * x - y),
        {"x": (0.8, 1.2), "y": (0.8, 1.2)},
        5.0,
        6,
        0.01,
    ),
    (
        "roessler",
        "x y z",
        ["-y - z", "x + 0.2*y", "0.2 + z*(x - 5.7)"],
        lambda x, y, z: (-y - z, x + 0.2 * y, 0.2 + z * (x - 5.7)),
        {"x": (-0.2, 0.2), "y": (-8.6, -8.2), "z": (-0.2, 0.2)},
        6.0,
        6,
        0.02,
    ),
]


def _simulate(f, points: np.ndarray, t_end: float):
    n, d = points.shape

    def rhs(_t, flat):
        s = flat.reshape(d, n)
        return np.concatenate([np.asarray(c, dtype=float) * np.ones(n) for c in f(*s)])

    sol = solve_ivp(rhs, (0.0, t_end), points.T.reshape(-1), method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    assert sol.success
    return lambda t: sol.sol(t).reshape(d, n).T


@pytest.mark.parametrize("system", SYSTEMS, ids=[s[0] for s in SYSTEMS])
def test_simulations_lie_inside_every_step(system):
    name, names, rhs, f, init, t_end, order, step = system
    variables = pv.variables(names)
    fp = pv.flowpipe(dict(zip(variables, rhs)), init=init, t_end=t_end, order=order, step=step)
    assert fp.time_reached == t_end and fp.failure is None
    box = pv.Box.coerce(init, names.split())
    points = box.sample(1000, seed=42)
    points[:4] = [[b[i % 2] for b in box.bounds] for i in range(4)]  # corners too
    trajectory = _simulate(f, points, t_end)
    tol = 1e-9  # the reference's own error at rtol = atol = 1e-12
    for (t0, t1), bounds in zip(fp.times, fp.array):
        for t in (t0, 0.5 * (t0 + t1), t1):
            states = trajectory(t)
            inside = np.all((states >= bounds[:, 0] - tol) & (states <= bounds[:, 1] + tol), axis=1)
            assert inside.all(), f"{name}: {np.count_nonzero(~inside)} trajectories leave the step box at t={t}"
    final = np.array([fp.final_box()[v] for v in names.split()])
    states = trajectory(t_end)
    assert np.all((states >= final[:, 0] - tol) & (states <= final[:, 1] + tol))
    # Not vacuous: the final box is a few times the sampled spread at most.
    spread = states.max(axis=0) - states.min(axis=0)
    assert np.all(final[:, 1] - final[:, 0] <= 10 * spread + 1e-3), (final, spread)


@pytest.mark.parametrize(
    "order, step, adaptive, t_end", [(6, 0.02, (0.001, 0.25), 3.0), ((4, 8), 0.1, None, 2.4)], ids=["adaptive-step", "adaptive-order"]
)
def test_adaptive_step_or_order_stays_sound(order, step, adaptive, t_end):
    x, y = pv.variables("x y")
    fp = pv.flowpipe(
        {x: y, y: (1 - x**2) * y - x},
        init={"x": (1.25, 1.55), "y": (2.28, 2.32)},
        t_end=t_end,
        order=order,
        step=step,
        adaptive=adaptive,
        remainder=1e-5,
    )
    assert fp.time_reached == t_end
    if adaptive:
        assert len(set(np.round(np.diff(fp.times, axis=1)[:, 0], 9))) > 1  # steps did adapt
    else:
        assert set(fp.orders) <= set(range(order[0], order[1] + 1))
    box = pv.Box.coerce({"x": (1.25, 1.55), "y": (2.28, 2.32)}, ["x", "y"])
    traj = _simulate(lambda a, b: (b, (1 - a * a) * b - a), box.sample(300, seed=3), t_end)
    for (t0, t1), bounds in zip(fp.times, fp.array):
        s = traj(0.5 * (t0 + t1))
        assert np.all((s >= bounds[:, 0] - 1e-9) & (s <= bounds[:, 1] + 1e-9))


def test_uncertain_parameter_and_piecewise_rhs():
    # x' = a*x with a in [-1.1, -0.9] encoded as an uncertain constant; and a clipped velocity.
    x, v = pv.variables("x v")
    fp = pv.flowpipe(
        {x: pv.uncertain(-1.1, -0.9) * x, v: pv.clip(1 - v, -0.5, 0.5)}, init={"x": (1, 1.1), "v": (0, 0.1)}, t_end=2.0, order=5, step=0.05
    )
    lo, hi = fp.final_box()["x"]
    assert lo <= 1.0 * np.exp(-1.1 * 2) and hi >= 1.1 * np.exp(-0.9 * 2)
    # v rises at the clipped rate 0.5 until v = 0.5 (at t = 1 - 2 v0), then relaxes: 1 - 0.5 e^-(2 - t).
    vlo, vhi = fp.final_box()["v"]
    assert vlo <= 1 - 0.5 * np.exp(-1.0) and vhi >= 1 - 0.5 * np.exp(-1.2)


class TestBadInput:
    def test_empty_and_nan_boxes(self):
        x = pv.variables("x")
        with pytest.raises(pv.InputError, match="lower bound"):
            pv.flowpipe({x: -x}, init={"x": (1, 0)}, t_end=1)
        with pytest.raises(pv.InputError, match="NaN"):
            pv.flowpipe({x: -x}, init={"x": (float("nan"), 1)}, t_end=1)

    def test_unknown_and_missing_variables(self):
        x, y = pv.variables("x y")
        with pytest.raises(pv.InputError, match="'y'"):
            pv.flowpipe({x: y}, init={"x": (0, 1)}, t_end=1)
        with pytest.raises(pv.InputError, match="missing"):
            pv.flowpipe({x: -x, y: x}, init={"x": (0, 1)}, t_end=1)

    def test_order_zero_and_negative_step(self):
        x = pv.variables("x")
        with pytest.raises(pv.InputError, match="order"):
            pv.flowpipe({x: -x}, init={"x": (0, 1)}, t_end=1, order=0)
        with pytest.raises(pv.InputError, match="step"):
            pv.flowpipe({x: -x}, init={"x": (0, 1)}, t_end=1, step=-0.1)
        with pytest.raises(pv.InputError, match="t_end"):
            pv.flowpipe({x: -x}, init={"x": (0, 1)}, t_end=-1)

    def test_blow_up_reports_time_and_keeps_partial_result(self):
        x = pv.variables("x")
        with pytest.raises(pv.BlowUpError, match="smaller step") as info:
            pv.flowpipe({x: x**2}, init={"x": (1, 1.1)}, t_end=2, order=4, step=0.05)
        partial = info.value.partial
        assert 0.5 < partial.time_reached < 1.0  # the solution from 1.1 explodes at t = 1/1.1
        assert len(partial.times) > 0
        fp = pv.flowpipe({x: x**2}, init={"x": (1, 1.1)}, t_end=2, order=4, step=0.05, on_failure="return")
        assert fp.failure and fp.time_reached == partial.time_reached

    def test_domain_error_is_reported(self):
        x = pv.variables("x")
        with pytest.raises(pv.BlowUpError, match="log"):
            pv.flowpipe({x: pv.log(x)}, init={"x": (-1, 1)}, t_end=1)

    def test_parse_errors_name_the_column(self):
        with pytest.raises(pv.ParseError, match="column"):
            pv.parse("x + * y")


def test_plot_and_json(tmp_path):
    x, y = pv.variables("x y")
    fp = pv.flowpipe({x: y, y: -x}, init={"x": (0.9, 1.1), "y": (0, 0.1)}, t_end=1.0, order=4, step=0.1)
    out = tmp_path / "fp.png"
    fp.plot("x", "y", path=str(out))
    assert out.stat().st_size > 1000
    doc = fp.to_json(str(tmp_path / "fp.json"))
    assert '"final_box"' in doc
    assert len(fp.boxes()) == len(fp.times) == 10
