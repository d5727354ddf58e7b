"""pv.uncertain(lo, hi, per="run"|"step"): a parameter held over a run (a constant of the system,
carried by verify as a state with zero dynamics) and a disturbance re-drawn each step (an interval
at every step). Runs simulated with plain numpy (parameters held, or drawn anew each step) stay
inside the reach sets of their semantics, and holding is tighter."""

import pickle

import numpy as np
import pytest

import percver as pv
from percver.errors import InputError
from percver.expr import held_parameters

x, k, u = pv.variables("x k u")
STEPS = 20


def _loop(per):
    """x' = (1 - a) x + a + 0.05 sin(x): for a held, x = 1 is a fixed point whatever a is."""
    a = pv.uncertain(0.0, 0.2, per=per)
    return pv.ClosedLoop(pv.Discrete({x: (1 - a) * x + a + 0.05 * pv.sin(x)}), stages=[]), a


def _numpy_runs(x0, a):
    """``a``: one value per run (N,) or per run and step (N x STEPS)."""
    runs = [x0]
    for t in range(STEPS):
        at = a[:, t] if a.ndim == 2 else a
        runs.append((1 - at) * runs[-1] + at + 0.05 * np.sin(runs[-1]))
    return np.stack(runs, axis=1)


def _assert_inside(result, runs, column=0):
    boxes = np.array(result.cells[0].boxes)[:, column]
    assert boxes.shape == (STEPS + 1, 2)
    assert np.all(runs >= boxes[:, 0] - 1e-12) and np.all(runs <= boxes[:, 1] + 1e-12)
    return boxes


def test_held_and_redrawn_parameters_enclose_their_runs_and_holding_is_tighter():
    rng = np.random.default_rng(0)
    n = 400
    x0 = rng.uniform(0.9, 1.0, n)
    widths = {}
    for per in ("run", "step"):
        loop, a = _loop(per)
        result = pv.verify(loop, init={"x": (0.9, 1.0)}, steps=STEPS, safe=x <= 10.0, progress=False)
        assert result.verdict == "verified"
        (pid, lo, hi), *_ = a.parameters()
        held = np.concatenate([[lo, hi], rng.uniform(lo, hi, n - 2)])
        # percver's own float simulation takes the same values as the numpy runs.
        np.testing.assert_allclose(loop.simulate(x0[:, None], STEPS, {pid: held})[:, :, 0], _numpy_runs(x0, held), atol=1e-12)
        boxes = _assert_inside(result, _numpy_runs(x0, held))
        if per == "run":
            assert result.states == ["x", "param_0"]  # the parameter is a state of the loop verified
            np.testing.assert_allclose(result.cells[0].boxes[0][1], (lo, hi))
        else:
            assert result.states == ["x"]
            redrawn = rng.uniform(lo, hi, (n, STEPS))
            redrawn[:2] = np.where(np.arange(STEPS) % 2, lo, hi)  # alternating extremes
            np.testing.assert_allclose(loop.simulate(x0[:, None], STEPS, {pid: redrawn})[:, :, 0], _numpy_runs(x0, redrawn), atol=1e-12)
            _assert_inside(result, _numpy_runs(x0, redrawn))
        widths[per] = boxes[-1, 1] - boxes[-1, 0]
    # Measured: 0.94 held against 9.9 re-drawn after 20 steps.
    assert widths["run"] < 0.2 * widths["step"]


def test_held_parameters_of_stages_and_continuous_plants():
    gain = pv.uncertain(0.5, 1.5, per="run")
    rate = pv.uncertain(0.8, 1.2, per="run")
    plant = pv.Continuous({x: -rate * x + u}, inputs=[u], period=0.1)
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(-gain * x, inputs=[x], output="u")])
    assert len(loop.held_parameters()) == 2
    result = pv.verify(loop, init={"x": (0.9, 1.1)}, steps=10, safe=x <= 2.0, progress=False)
    assert result.verdict == "verified" and len(result.states) == 3
    rng = np.random.default_rng(1)
    values = {pid: rng.uniform(lo, hi, 200) for pid, lo, hi in loop.parameters()}
    x0 = rng.uniform(0.9, 1.1, (200, 1))
    runs = loop.simulate(x0, 10, values)[:, :, 0]
    # The exact solution of x' = -rate x + u over a period with u = -gain x held from its start.
    g, r = (values[p.parameters()[0][0]] for p in (gain, rate))
    decay = np.exp(-r * 0.1)
    np.testing.assert_allclose(runs[:, -1], x0[:, 0] * (decay - g * (1 - decay) / r) ** 10, rtol=1e-6)
    boxes = np.array(result.cells[0].boxes)[:, 0]
    assert np.all(runs >= boxes[:, 0] - 1e-9) and np.all(runs <= boxes[:, 1] + 1e-9)


def test_counterexample_records_held_values_and_replays_on_the_loop_as_given():
    loop, a = _loop("run")
    result = pv.verify(loop, init={"x": (0.9, 1.0)}, steps=STEPS, safe=x <= 1.02, progress=False)
    cex = result.counterexample
    assert result.verdict == "falsified" and cex.parameters[0]["id"] == a.parameters()[0][0]
    assert list(cex.initial) == ["x"] and len(cex.trajectory[0]) == 1  # a run of the loop as given
    assert 0.0 <= cex.parameters[0]["value"] <= 0.2
    replay = loop.simulate([[cex.initial["x"]]], cex.step, parameters=cex.parameter_values())
    np.testing.assert_allclose(replay[0, :, 0], np.array(cex.trajectory)[:, 0], atol=1e-12)


def test_per_is_kept_by_pickling_and_bad_values_are_refused():
    held, step = pv.uncertain(0, 1, per="run"), pv.uncertain(0, 1)
    e = pickle.loads(pickle.dumps(held * x + step))
    assert [p[0] for p in held_parameters(e)] == [held.parameters()[0][0]]
    with pytest.raises(InputError, match="per='step'.*per='run'"):
        pv.uncertain(0, 1, per="episode")
    with pytest.raises(InputError, match="simulate|runs x steps"):
        _loop("step")[0].simulate([[1.0]], 3, {_loop("step")[1].parameters()[0][0]: np.zeros((1, 2))})
