"""Sets to avoid and to reach (boxes, pv.all_of, pv.any_of) and properties with a time window
(pv.during): what they mean, checked against plain numpy runs, and that the engine's single
condition per set is never weaker than the set (sampled)."""

import numpy as np
import pytest

import percver as pv
from closed_loops import check_against_simulation

x1, x2, x = pv.variables("x1 x2 x")


def drift():
    """x1 falls by 0.05 a step, x2 stays: from x2 = 0.5 the runs cross the strip -0.2 <= x1 <= 0
    but never the box that also asks x2 <= 0."""
    return pv.ClosedLoop(pv.Discrete({x1: x1 - 0.05, x2: x2}))


def numpy_drift(x0, steps):
    return np.stack([x0 + np.array([-0.05 * k, 0.0]) for k in range(steps + 1)], axis=1)


BOX = {"x1": (-0.2, 0.0), "x2": (-1.0, 0.0)}
AWAY, INTO = {"x1": (0.5, 0.6), "x2": (0.5, 0.6)}, {"x1": (0.5, 0.6), "x2": (-0.5, -0.4)}


def in_box(traj, box):
    return (traj[..., 0] >= box["x1"][0]) & (traj[..., 0] <= box["x1"][1]) & (traj[..., 1] >= box["x2"][0]) & (traj[..., 1] <= box["x2"][1])


@pytest.mark.parametrize(
    "unsafe",
    [
        [x1 >= -0.2, x1 <= 0, x2 >= -1, x2 <= 0],  # a list of conditions is one set: the box
        pv.Box(BOX),
        BOX,
        pv.all_of(x1 >= -0.2, x1 <= 0, pv.Box({"x2": (-1, 0)})),
    ],
    ids=["list", "Box", "dict", "all_of"],
)
def test_a_box_to_avoid_is_one_set(unsafe):
    runs = numpy_drift(pv.Box(AWAY).sample(500, seed=2), 20)
    assert not in_box(runs, BOX).any() and ((runs[..., 0] >= -0.2) & (runs[..., 0] <= 0)).any()
    res = pv.verify(drift(), init=AWAY, steps=20, unsafe=unsafe, progress=False)
    assert res.verdict == "verified", res.cells[0].reason
    assert check_against_simulation(drift(), dict(unsafe=unsafe), res) > 0
    res = pv.verify(drift(), init=INTO, steps=20, unsafe=unsafe, progress=False)
    cex = res.counterexample
    assert res.verdict == "falsified" and in_box(np.asarray(cex.trajectory)[cex.step], BOX)
    replay = numpy_drift(np.array([[cex.initial["x1"], cex.initial["x2"]]]), cex.step)[0]
    np.testing.assert_allclose(np.asarray(cex.trajectory), replay, atol=1e-12)


def test_any_of_is_several_sets_to_avoid():
    """Avoid either of two boxes: the runs from INTO enter the second."""
    far = pv.Box({"x1": (5, 6), "x2": (5, 6)})
    assert pv.verify(drift(), init=AWAY, steps=20, unsafe=pv.any_of(far, pv.Box(BOX)), progress=False).verdict == "verified"
    res = pv.verify(drift(), init=INTO, steps=20, unsafe=pv.any_of(far, pv.Box(BOX)), progress=False)
    cex = res.counterexample
    assert res.verdict == "falsified" and in_box(np.asarray(cex.trajectory)[cex.step], BOX) and cex.violated.startswith("unsafe ")
    with pytest.raises(pv.InputError, match="for several sets to avoid write unsafe=pv.any_of"):
        pv.verify(drift(), init=AWAY, steps=2, unsafe=[far, pv.Box(BOX)], progress=False)


def test_a_box_to_reach_and_a_box_to_stay_in():
    goal = pv.Box({"x1": (-0.55, -0.35)})
    res = pv.verify(drift(), init=AWAY, steps=20, goal=goal, safe=pv.Box({"x2": (0, 1)}), progress=False)
    assert res.verdict == "verified"  # x1 at step 20 in [-0.5, -0.4]
    assert pv.verify(drift(), init=AWAY, steps=16, goal=goal, progress=False).verdict == "falsified"


@pytest.mark.parametrize(
    "make",
    [
        lambda: pv.all_of(x1 >= 0.1, x2 < 0.3, x1 + x2 <= 1),
        lambda: pv.any_of(x1 > 0.4, pv.all_of(x2 >= -0.2, x1 * x2 <= 0.05)),
        lambda: pv.any_of(pv.Box({"x1": (0, 0.5), "x2": (0, 0.5)}), x1 + x2 > 0.8),
    ],
)
def test_the_engines_condition_is_never_weaker_and_complements_are_exact(make):
    region = make()
    pts = np.random.default_rng(0).uniform(-1, 1, size=(20000, 2))
    pts[:500] = np.round(pts[:500] * 10) / 10  # on the boundaries too
    exact = region.holds(["x1", "x2"], pts)
    c = region.condition()
    m = pv.evaluate(c.margin(), {"x1": pts[:, 0], "x2": pts[:, 1]})
    combined = {"<": m < 0, "<=": m <= 0, ">": m > 0, ">=": m >= 0}[c.op]
    assert not (combined & ~exact).any() and (combined == exact).mean() > 0.95
    np.testing.assert_array_equal(region.complement().holds(["x1", "x2"], pts), ~exact)
    out = region.complement().condition()
    m = pv.evaluate(out.margin(), {"x1": pts[:, 0], "x2": pts[:, 1]})
    assert not ({"<": m < 0, "<=": m <= 0, ">": m > 0, ">=": m >= 0}[out.op] & exact).any()


# ----------------------------------------------------------------------------- windows


def rise():
    return pv.ClosedLoop(pv.Discrete({x: x + 0.1}))


def test_a_window_of_steps():
    init = {"x": (0, 0.05)}
    assert pv.verify(rise(), init=init, steps=10, safe=x >= 0.49, progress=False).verdict == "falsified"
    res = pv.verify(rise(), init=init, steps=10, safe=pv.during(x >= 0.49, steps=(5, 10)), progress=False)
    assert res.verdict == "verified", res.cells[0].reason
    assert check_against_simulation(rise(), dict(safe=pv.during(x >= 0.49, steps=(5, 10))), res) > 0
    res = pv.verify(rise(), init=init, steps=10, safe=pv.during(x >= 0.49, steps=(4, None)), progress=False)
    assert res.verdict == "falsified" and res.counterexample.step == 4 and "for steps [4, 10]" in res.counterexample.violated
    # Avoided only in a window: the runs pass x in [0.2, 0.3] at steps 2-3 only.
    strip = pv.Box({"x": (0.2, 0.3)})
    assert pv.verify(rise(), init=init, steps=10, unsafe=pv.during(strip, steps=(4, 10)), progress=False).verdict == "verified"
    assert pv.verify(rise(), init=init, steps=10, unsafe=pv.during(strip, steps=(0, 3)), progress=False).verdict == "falsified"


def climb(period=0.1):
    """x' = 1: at time t the runs are at x0 + t."""
    return pv.ClosedLoop(pv.Continuous({x: 1.0}, period=period))


def test_a_window_in_time_on_a_continuous_plant():
    init = {"x": (0, 0.05)}
    # "x >= 0.49 for t in [0.5, 1]": holds from t = 0.5 on, and not on the segment before it.
    res = pv.verify(climb(), init=init, steps=10, safe=pv.during(x >= 0.49, time=(0.5, 1)), progress=False)
    assert res.verdict == "verified", res.cells[0].reason
    # From t = 0.45 (inside period 4) it fails between steps: the flowpipe segments there catch it.
    res = pv.verify(climb(), init=init, steps=10, safe=pv.during(x >= 0.49, time=(0.45, 1)), falsify=0, progress=False)
    assert res.verdict == "unknown" and "could not be proved over t in" in res.cells[0].reason
    # "for t > 0.8": an upper bound reached only before it is no violation.
    assert pv.verify(climb(), init=init, steps=10, safe=pv.during(x >= 0.79, time=(0.8, None)), progress=False).verdict == "verified"
    assert pv.verify(climb(), init=init, steps=10, unsafe=pv.during(x <= 0.3, time=(0.35, None)), progress=False).verdict == "verified"
    res = pv.verify(climb(), init=init, steps=10, unsafe=pv.during(x <= 0.3, time=(0.25, None)), falsify=0, progress=False)
    assert res.verdict != "verified"


def test_reach_avoid_goal_at_the_end_obstacle_at_all_times():
    """NAV's form: the goal at the last step, an obstacle never entered."""
    loop = pv.ClosedLoop(pv.Discrete({x1: x1 + 0.1, x2: x2 + 0.1 * pv.sin(3 * x1)}))
    init = {"x1": (0, 0.05), "x2": (0, 0.05)}
    goal = pv.Box({"x1": (1.9, 2.2)})
    runs = loop.simulate(pv.Box(init).sample(300, seed=3), 20)
    for obstacle in ({"x1": (0.9, 1.1), "x2": (0.8, 1.2)}, {"x1": (0.9, 1.1), "x2": (0.6, 0.7)}):
        entered = in_box(runs, obstacle).any()
        res = pv.verify(loop, init=init, steps=20, goal=goal, unsafe=pv.Box(obstacle), progress=False)
        assert res.verdict == ("falsified" if entered else "verified"), res.cells[0].reason
        if entered:
            cex = res.counterexample
            assert in_box(np.asarray(cex.trajectory)[cex.step], obstacle)
        else:
            boxes = np.asarray(res.cells[0].boxes)
            assert np.all((runs >= boxes[None, :, :, 0]) & (runs <= boxes[None, :, :, 1]))
    assert pv.verify(loop, init=init, steps=18, goal=goal, unsafe=pv.Box({"x2": (5, 6)}), progress=False).verdict == "falsified"


def test_bad_windows_are_refused():
    with pytest.raises(pv.InputError, match="exactly one of steps"):
        pv.during(x >= 0, steps=(1, 2), time=(0, 1))
    with pytest.raises(pv.InputError, match="whole steps"):
        pv.during(x >= 0, steps=(1.5, 2))
    with pytest.raises(pv.InputError, match="not end before it starts"):
        pv.during(x >= 0, time=(2, 1))
    with pytest.raises(pv.InputError, match="needs a continuous plant"):
        pv.verify(rise(), init={"x": (0, 0)}, steps=2, safe=pv.during(x >= 0, time=(0, 1)), progress=False)
    with pytest.raises(pv.InputError, match="goal= takes no window"):
        pv.verify(rise(), init={"x": (0, 0)}, steps=2, goal=pv.during(x >= 0, steps=(0, 1)), progress=False)
