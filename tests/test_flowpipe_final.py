"""Flow* benchmark models with their own files' settings (Lorenz to its horizon T = 7 among
them): every simulated trajectory (scipy DOP853, rtol = atol = 1e-12) from corners and random
points of the initial box must lie in every step's box, in the final box under every bounder,
and in the final Taylor models' enclosures evaluated at its own initial point."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv
from percver.errors import InputError

MODELS = Path(__file__).resolve().parents[1].parent / "shared" / "anchors" / "flowstar_models"

# (file, horizon to use (None: the file's), number of random points)
CASES = [("tb_lorenz", None, 200), ("tb_vanderpol", None, 400), ("tb_laubloomis", 4.0, 100)]


# Plain numpy right-hand sides, written from the model files independently of percver.
RHS = {
    "tb_lorenz": lambda x, y, z: (10 * (y - x), x * (28 - z) - y, x * y - 2.67 * z),
    "tb_vanderpol": lambda x, y, t: (y, (1 - x**2) * y - x, np.ones_like(t)),
    "tb_laubloomis": lambda x1, x2, x3, x4, x5, x6, x7, t: (
        1.4 * x3 - 0.9 * x1,
        2.5 * x5 - 1.5 * x2,
        0.6 * x7 - 0.8 * x3 * x2,
        2 - 1.3 * x4 * x3,
        0.7 * x1 - x4 * x5,
        0.3 * x1 - 3.1 * x6,
        1.8 * x6 - 1.5 * x7 * x2,
        np.ones_like(t),
    ),
}


def _points(model, count):
    box = pv.Box.coerce({v: model.init[v] for v in model.variables}, model.variables)
    lo, hi = np.array(box.bounds).T
    corners = np.array([[hi[j] if (i >> j) & 1 else lo[j] for j in range(len(lo))] for i in range(min(2 ** len(lo), 64))])
    return np.vstack([corners, box.sample(count, seed=3)])


def _simulate(name, model, points, t_end):
    f = RHS[name]

    def rhs(_t, flat):
        return np.concatenate(f(*flat.reshape(len(model.variables), -1)))

    sol = solve_ivp(rhs, (0.0, t_end), points.T.reshape(-1), method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    assert sol.success
    d = len(model.variables)
    return lambda t: sol.sol(t).reshape(d, -1).T


@pytest.fixture(scope="module", params=CASES, ids=[c[0] for c in CASES])
def case(request):
    name, horizon, count = request.param
    model = pv.formats.load_flowstar(str(MODELS / f"{name}.model"))
    if horizon is not None:
        model = dataclasses.replace(model, t_end=horizon)
    fp = model.run()
    points = _points(model, count)
    return name, model, fp, points, _simulate(name, model, points, model.t_end)


def _inside(states, bounds, tol):
    return np.all((states >= bounds[:, 0] - tol) & (states <= bounds[:, 1] + tol), axis=1)


def test_every_step_box_holds_the_trajectories(case):
    name, model, fp, points, trajectory = case
    assert fp.failure is None and fp.time_reached == model.t_end
    # The reference's own error, grown by the flow's expansion (Lorenz is chaotic).
    tol = 1e-7 if name == "tb_lorenz" else 1e-9
    for (t0, t1), bounds in zip(fp.times, fp.array):
        for t in (t0, t0 + 0.3 * (t1 - t0), t1):
            inside = _inside(trajectory(min(t, model.t_end)), bounds, tol)
            assert inside.all(), f"{name}: {np.count_nonzero(~inside)} trajectories leave the step box at t={t}"


def test_final_boxes_under_every_bounder_hold_the_trajectories(case):
    name, model, fp, points, trajectory = case
    final = trajectory(model.t_end)
    tol = 1e-7 if name == "tb_lorenz" else 1e-9
    widths = {}
    for bounder, split in [("dominated", None), ("interval", None), ("subdivision", 3), ("bernstein", None)]:
        try:
            box = fp.final_box(bounder, split)
        except InputError as e:  # Bernstein is refused where it would cost too much
            assert bounder == "bernstein" and "Bernstein" in str(e)
            continue
        bounds = np.array([box[v] for v in model.variables])
        assert _inside(final, bounds, tol).all(), f"{name}: {bounder} box misses trajectories"
        widths[bounder] = bounds[:, 1] - bounds[:, 0]
    # Subdivision keeps the dominated bound where that is tighter: never wider than either.
    assert np.all(widths["subdivision"] <= np.minimum(widths["dominated"], widths["interval"]) * (1 + 1e-12))
    # Not vacuous: at most a few times the simulated spread.
    spread = final.max(axis=0) - final.min(axis=0)
    assert np.all(widths["subdivision"] <= 10 * spread + 1e-3), (widths, spread)


def test_final_models_enclose_each_trajectory_end(case):
    name, model, fp, points, trajectory = case
    final = trajectory(model.t_end)
    tol = 1e-7 if name == "tb_lorenz" else 1e-9
    enclosures = fp.final_enclose(points)
    assert enclosures.shape == (len(points), len(model.variables), 2)
    for j in range(len(model.variables)):
        lo, hi = enclosures[:, j, 0], enclosures[:, j, 1]
        assert np.all((final[:, j] >= lo - tol) & (final[:, j] <= hi + tol)), f"{name}: model {model.variables[j]} misses"
    models = fp.final_models()
    assert [m.name for m in models] == model.variables
    for j, m in enumerate(models):
        np.testing.assert_array_equal(m.enclose(points), enclosures[:, j, :])
        # The float polynomial plus the remainder lands on the rigorous enclosure.
        p = m.polynomial(points)
        assert np.all(p + m.remainder[0] <= enclosures[:, j, 1] + 1e-9) and np.all(p + m.remainder[1] >= enclosures[:, j, 0] - 1e-9)
    # Per-point enclosures are much tighter than the final box where the set is wide.
    box = np.array([fp.final_box()[v] for v in model.variables])
    per_point = (enclosures[:, :, 1] - enclosures[:, :, 0]).max(axis=0)
    wide = box[:, 1] - box[:, 0] > 1e-6
    assert np.all(per_point[wide] < box[wide, 1] - box[wide, 0])


def test_final_model_errors_are_clear():
    model = pv.formats.load_flowstar(str(MODELS / "tb_vanderpol.model"))
    fp = dataclasses.replace(model, t_end=0.5).run()
    with pytest.raises(InputError, match="not in the initial box"):
        fp.final_enclose([[0.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="columns"):
        fp.final_enclose([[1.2, 2.4]])
    with pytest.raises(InputError, match="unknown bounder"):
        fp.final_box("hull")
    with pytest.raises(InputError, match="split"):
        fp.final_box(split=0)
