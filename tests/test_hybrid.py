"""Hybrid plants (pv.Hybrid): modes, guards, resets inside a control period, verified with
Taylor models carried through the jumps and checked against an independent float simulation."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv
from percver.networks import Layer, Network

x, v, c, u = (pv.Expr.var(n) for n in "x v c u".split())
PERIOD, G, BOUNCE = 0.1, 9.81, 0.8


def controller() -> Network:
    return Network(
        [
            Layer(np.array([[-0.8, -1.2], [0.3, -0.5]]), np.array([0.0, 0.1]), "tanh"),
            Layer(np.array([[1.0, 0.5]]), np.array([0.0]), "identity"),
        ]
    )


def ball_loop(gravity=G, bounce=BOUNCE) -> pv.ClosedLoop:
    """A ball pushed by a network, bouncing on the floor; the clock c ends each period."""
    plant = pv.Hybrid(
        {"fly": pv.Mode({x: v, v: u - gravity, c: 1}, invariant=[x >= 0, c <= PERIOD])},
        [pv.Jump("fly", "fly", guard=[x <= 0, v <= 0], reset={v: -bounce * v}), pv.Jump("fly", None, guard=[c >= PERIOD], reset={c: 0})],
        inputs=[u],
        max_time=0.5,
        step=0.01,
    )
    return pv.ClosedLoop(plant, [pv.Stage(controller(), [x, v], "u")])


def simulate_ball(x0: np.ndarray, steps: int, gravity=G, bounce=BOUNCE) -> np.ndarray:
    """The ball's runs by scipy (DOP853, the floor as a terminal event), written from the
    physics, not from pv.Hybrid: trajectories N x (steps + 1) x 2 of (x, v) at period ends.
    ``gravity`` and ``bounce`` are numbers or one value per run."""
    net = controller()
    out = np.empty((len(x0), steps + 1, 2))
    gravity, bounce = np.broadcast_to(gravity, len(x0)), np.broadcast_to(bounce, len(x0))
    for r, (xi, vi) in enumerate(x0):
        out[r, 0] = xi, vi
        for k in range(steps):
            ui = float(net(np.array([[xi, vi]]))[0, 0])
            t, y = 0.0, np.array([xi, vi])
            floor = lambda _t, y: y[0]
            floor.terminal, floor.direction = True, -1
            while t < PERIOD:
                sol = solve_ivp(
                    lambda _t, y: [y[1], ui - gravity[r]],
                    (t, PERIOD),
                    y,
                    method="DOP853",
                    rtol=1e-12,
                    atol=1e-13,
                    events=floor if y[0] > 1e-12 or y[1] > 0 else None,
                )
                t, y = sol.t[-1], sol.y[:, -1].copy()
                if sol.status == 1:
                    y = np.array([0.0, -bounce[r] * y[1]])
            xi, vi = y
            out[r, k + 1] = xi, vi
    return out


def test_bouncing_ball_in_a_closed_loop_encloses_every_simulated_run():
    loop = ball_loop()
    steps = 7  # the floor is hit in period 5 and left behind
    init = {x: (1.0, 1.1), v: (-0.1, 0.1), c: (0.0, 0.0)}
    result = pv.verify(loop, init, steps=steps, safe=[x >= -0.3], max_splits=2, progress=False)
    assert result.cells and all(cell.boxes for cell in result.cells)
    rng = np.random.default_rng(7)
    x0 = np.column_stack([rng.uniform(1.0, 1.1, 2000), rng.uniform(-0.1, 0.1, 2000)])
    x0[:4] = [[1.0, -0.1], [1.0, 0.1], [1.1, -0.1], [1.1, 0.1]]
    traj = simulate_ball(x0, steps)
    assert (traj[:, 5, 1] > 0).all(), "the runs bounce in period 5"
    for cell in result.cells:
        box = cell.box
        inside = (x0[:, 0] >= box["x"][0]) & (x0[:, 0] <= box["x"][1]) & (x0[:, 1] >= box["v"][0]) & (x0[:, 1] <= box["v"][1])
        for t, b in enumerate(np.asarray(cell.boxes)):
            for j in range(2):
                part = traj[inside, t, j]
                assert ((part >= b[j, 0] - 1e-9) & (part <= b[j, 1] + 1e-9)).all(), (t, j, b[j], part.min(), part.max())
    assert result.verdict == "verified", [cell.reason for cell in result.cells]
    # The package's own float simulation agrees with the physics.
    assert np.allclose(loop.simulate(np.column_stack([x0[:20], np.zeros(20)]), steps)[:, :, :2], traj[:20], atol=1e-6)


def test_parameters_held_over_a_run_are_constant_states_of_every_mode():
    """Gravity and the bounce held over a run (pv.uncertain(..., per="run")): a state of rate 0 in
    every mode that no jump resets; scipy runs with one drawn pair per run stay in the reach sets."""
    gravity, bounce = pv.uncertain(9.6, 10.0, per="run"), pv.uncertain(0.7, 0.85, per="run")
    loop = ball_loop(gravity, bounce)
    held = loop.with_held_parameters()
    assert held.states == ["x", "v", "c", "param_0", "param_1"]
    assert all(pv.evaluate([mode.rhs["param_0"], mode.rhs["param_1"]], {}).tolist() == [[0.0, 0.0]] for mode in held.plant.modes.values())
    assert all("param_0" not in j.reset and "param_1" not in j.reset for j in held.plant.jumps)
    steps = 7
    result = pv.verify(loop, {x: (1.0, 1.1), v: (-0.1, 0.1), c: (0.0, 0.0)}, steps=steps, safe=[x >= -0.3], max_splits=2, progress=False)
    assert result.states == ["x", "v", "c", "param_0", "param_1"]
    rng = np.random.default_rng(8)
    n = 300
    x0 = np.column_stack([rng.uniform(1.0, 1.1, n), rng.uniform(-0.1, 0.1, n)])
    (g_id, g_lo, g_hi), (b_id, b_lo, b_hi) = loop.held_parameters()
    g, b = rng.uniform(g_lo, g_hi, n), rng.uniform(b_lo, b_hi, n)
    g[:4], b[:4] = [g_lo, g_hi, g_lo, g_hi], [b_lo, b_lo, b_hi, b_hi]
    traj = simulate_ball(x0, steps, g, b)
    assert (traj[:, 5, 1] > 0).all(), "the runs bounce in period 5"
    # The package's float simulation of the loop as given holds the same values.
    replay = loop.simulate(np.column_stack([x0[:10], np.zeros(10)]), steps, {g_id: g[:10], b_id: b[:10]})
    np.testing.assert_allclose(replay[:, :, :2], traj[:10], atol=1e-6)
    for cell in result.cells:
        box = cell.box
        inside = np.ones(n, dtype=bool)
        for j, value in enumerate((x0[:, 0], x0[:, 1], g, b)):
            lo, hi = box[result.states[[0, 1, 3, 4][j]]]
            inside &= (value >= lo) & (value <= hi)
        for t, bounds in enumerate(np.asarray(cell.boxes)):
            for j in range(2):
                part = traj[inside, t, j]
                assert ((part >= bounds[j, 0] - 1e-9) & (part <= bounds[j, 1] + 1e-9)).all(), (t, j, bounds[j], part.min(), part.max())
            # Held through every flow and jump: the parameters' boxes are the cell's ranges at every step.
            np.testing.assert_allclose(bounds[3:], [box["param_0"], box["param_1"]], atol=1e-9)
    assert result.verdict == "verified", [cell.reason for cell in result.cells]


def test_hybrid_plant_errors_name_the_fix():
    fly = pv.Mode({x: v, v: -G})
    with pytest.raises(pv.InputError, match="no jump returns to the controller"):
        pv.ClosedLoop(pv.Hybrid({"fly": fly}, [pv.Jump("fly", "fly", guard=[x <= 0])], max_time=1, step=0.1))
    with pytest.raises(pv.InputError, match="names mode"):
        pv.Hybrid({"fly": fly}, [pv.Jump("fly", "land", guard=[x <= 0]), pv.Jump("fly", None)], max_time=1, step=0.1)
    with pytest.raises(pv.InputError, match="not states"):
        pv.Hybrid({"fly": fly}, [pv.Jump("fly", None, reset={u: 0})], max_time=1, step=0.1)
    with pytest.raises(pv.InputError, match="neither its states nor its inputs"):
        pv.Hybrid({"fly": pv.Mode({x: v, v: u})}, [pv.Jump("fly", None)], max_time=1, step=0.1)


def _ode(rates: dict) -> str:
    names = ["_f1", "_f2", "x0", "x1", "u", "worldtime", "clock"]
    return "nonpoly ode\n{\n" + "\n".join(f"{v}' = {rates.get(v, '0')}" for v in names) + "\n}"


def _mode(name: str, rates: dict, clock_bound: float) -> str:
    return f"{name}\n{{\n{_ode(rates)}\ninv\n{{\nclock <= {clock_bound}\n}}\n}}"


def _segments_model(path, horizon: float, bound: float) -> None:
    """A Verisig 2.0-style model whose period runs through two plant modes with different
    dynamics (seg_a, then seg_b after 0.05 s), like the quadrotor MPC benchmark's segments."""
    frozen = {"clock": "1"}
    flow = {"worldtime": "1", "clock": "1"}
    modes = [
        _mode("m0", frozen, 0),
        _mode("DNNm1", frozen, 0),
        _mode("startmode", frozen, 0),
        _mode("unsafe1", frozen, 1),
        _mode("seg_a", {**flow, "x0": "x1", "x1": "u - x0"}, 0.05),
        _mode("seg_b", {**flow, "x0": "x1", "x1": "u * x1 * x1 - x0"}, 0.05),
    ]
    jumps = [
        ("m0", "DNNm1", "", "clock' := 0"),
        ("DNNm1", "seg_a", "", "u' := 2.0 * _f1 clock' := 0.0"),
        ("seg_a", "seg_b", "clock = 0.05", "clock' := 0.0"),
        ("seg_b", "m0", "clock = 0.05", "_f2' := x1 _f1' := x0 clock' := 0.0"),
        ("seg_b", "unsafe1", f"worldtime = {horizon} x0 >= {bound}", "clock' := 0.0"),
        ("startmode", "m0", "clock = 0.0", "_f2' := x1 _f1' := x0 clock' := 0.0"),
    ]
    text = f"""hybrid reachability
{{
state var _f1, _f2, x0, x1, u, worldtime, clock
setting
{{
adaptive steps {{min 1e-6, max 0.005}}
time {horizon}
remainder estimation 1e-1
identity precondition
matlab octagon x0, x1
fixed orders 4
cutoff 1e-10
precision 100
output segments
max jumps 500
print on
}}
modes
{{
{chr(10).join(modes)}
}}
jumps
{{
{chr(10).join(f"{a} -> {b}{chr(10)}guard {{ {g} }}{chr(10)}reset {{ {r} }}{chr(10)}interval aggregation" for a, b, g, r in jumps)}
}}
init
{{
startmode
{{
x0 in [0.8, 0.9]
x1 in [0.5, 0.6]
_f1 in [0, 0]
_f2 in [0, 0]
u in [0, 0]
worldtime in [0, 0]
clock in [0, 0]
}}
}}
}}
unsafe
{{
unsafe1
{{
x0 >= {bound}
}}
}}
"""
    path.write_text(text)


def test_verisig_model_with_two_plant_modes_per_period_is_verified(tmp_path):
    from percver.formats.verisig_yaml import write_verisig_yaml

    net = Network(
        [
            Layer(np.array([[-0.5, -0.4], [0.2, -0.3]]), np.array([0.0, 0.1]), "tanh"),
            Layer(np.array([[0.8, 0.5]]), np.array([0.0]), "identity"),
        ]
    )
    write_verisig_yaml(net, tmp_path / "net.yml")
    _segments_model(tmp_path / "segments.model", horizon=0.5, bound=2.0)
    problem = pv.load_verisig(str(tmp_path / "segments.model"), networks=[str(tmp_path / "net.yml")])
    assert isinstance(problem.loop.plant, pv.Hybrid) and list(problem.loop.plant.modes) == ["seg_a", "seg_b"]
    assert problem.steps == 5
    result = problem.verify(progress=False)
    assert result.verdict == "verified", [c.reason for c in result.cells]
    # Every simulated run (scipy through both modes, written here from the model) lies in the boxes.
    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(0.8, 0.9, 1000), rng.uniform(0.5, 0.6, 1000)])
    runs = []
    for row in x0:
        state, traj = row.copy(), [row.copy()]
        for _ in range(5):
            u0 = 2.0 * float(net(state[None, :])[0, 0])
            for f in (lambda _t, y: [y[1], u0 - y[0]], lambda _t, y: [y[1], u0 * y[1] ** 2 - y[0]]):
                state = solve_ivp(f, (0, 0.05), state, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
            traj.append(state.copy())
        runs.append(traj)
    runs = np.asarray(runs)
    names = result.states
    for cell in result.cells:
        boxes = np.asarray(cell.boxes)
        for j, name in enumerate(("x0", "x1")):
            k = names.index(name)
            assert (
                (runs[:, : len(boxes), j] >= boxes[None, :, k, 0] - 1e-9) & (runs[:, : len(boxes), j] <= boxes[None, :, k, 1] + 1e-9)
            ).all()
    # A bound the runs cross is not verified.
    _segments_model(tmp_path / "tight.model", horizon=0.5, bound=float(runs[:, -1, 0].max()) - 0.05)
    tight = pv.load_verisig(str(tmp_path / "tight.model"), networks=[str(tmp_path / "net.yml")])
    assert tight.verify(progress=False).verdict != "verified"
