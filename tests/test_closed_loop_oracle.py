"""The sampling oracle over every closed loop of the catalogue (tests/closed_loops.py): 1,000
simulated trajectories per cell inside the per-step reach boxes, and no sampled violation in a
verified cell. Plus accumulators (reward=) and a known-unsafe start falsified with a replaying
counterexample."""

import numpy as np
import pytest

import percver as pv
from closed_loops import CASES, check_against_simulation, continuous_tanh, mountain_car, verified_loop

# The verdict each case must reach (the Verisig suite: as Verisig 2.0 did); None: refined, no falsified cell.
EXPECTED = {"mc_refined": None}


@pytest.mark.parametrize("name", sorted(CASES))
def test_reach_boxes_contain_1000_simulations_per_cell(name):
    target, kwargs = CASES[name]()
    res = pv.verify(target, progress=False, **kwargs)
    expected = EXPECTED.get(name, "verified")
    if expected:
        assert res.verdict == expected, [c.reason for c in res.cells]
    else:
        assert len(res.cells) > 1 and "falsified" not in {c.verdict for c in res.cells}, [c.reason for c in res.cells]
    assert check_against_simulation(target, kwargs, res) > 0


def test_reward_accumulates_along_the_run():
    """Mountain Car's reward: -0.1 u^2 per step; reaching p >= 0.45 with reward + 100 > 90 (issue 5's property)."""
    loop, p, v, u = mountain_car()
    r = pv.variables("r")
    reward = {"r": -0.1 * u**2}
    res = pv.verify(
        loop,
        init={"p": (-0.53, -0.5), "v": (0, 0)},
        steps=150,
        reward=reward,
        goal=[p >= 0.45, r + 100 > 90],
        within=True,
        split={"p": 2},
        progress=False,
    )
    assert res.verdict == "verified" and res.states == ["p", "v", "r"]
    # The accumulator is the running sum of the controller's cost, as simulated without it.
    x0 = np.array([[-0.51, 0.0]])
    plain = loop.simulate(x0, 100)[0]
    controls = np.asarray(loop.stages[0].component(plain[:-1])).ravel()
    summed = loop.with_accumulators(reward).simulate(np.array([[-0.51, 0.0, 0.0]]), 100)[0]
    np.testing.assert_allclose(summed[:, :2], plain, atol=0)
    np.testing.assert_allclose(summed[1:, 2], np.cumsum(-0.1 * controls**2), rtol=1e-12)
    # The final reach box of r encloses what the runs collect, and is tight (not vacuous).
    final = np.asarray(res.cells[0].boxes)[-1][2]
    assert -10 < final[0] <= final[1] < 0 and final[1] - final[0] < 0.5
    # A stricter reward bound is out of reach: not verified, and the sampled runs show why.
    strict = pv.verify(
        loop, init={"p": (-0.53, -0.5), "v": (0, 0)}, steps=150, reward=reward, goal=[p >= 0.45, r > -5], within=True, progress=False
    )
    assert strict.verdict == "falsified" and "goal" in strict.counterexample.violated


def test_continuous_accumulator_gains_the_step_increment_per_period():
    loop, x, v, u = continuous_tanh()
    summed = loop.with_accumulators({"n": 1.0, "ux": u * x})
    traj = summed.simulate(np.array([[1.0, 0.05, 0.0, 0.0]]), 10)[0]
    np.testing.assert_allclose(traj[:, 2], np.arange(11), rtol=1e-9)
    plain = loop.simulate(np.array([[1.0, 0.05]]), 10)[0]
    controls = np.asarray(loop.stages[0].component(plain[:-1])).ravel()
    np.testing.assert_allclose(traj[1:, 3], np.cumsum(controls * plain[:-1, 0]), rtol=1e-8)


def test_known_unsafe_start_falsified_with_a_counterexample_that_replays():
    """From p0 = -0.6 the sig16x16 controller does not reach the goal within 150 steps; with the reward
    the counterexample carries the sum, and replaying it reproduces the violation."""
    loop, p, v, u = mountain_car()
    r = pv.variables("r")
    kwargs = dict(init={"p": (-0.6, -0.6), "v": (0, 0)}, steps=150, reward={"r": -0.1 * u**2}, goal=[p >= 0.45, r + 100 > 90], within=True)
    res = pv.verify(loop, progress=False, **kwargs)
    assert res.verdict == "falsified"
    cex = res.counterexample
    assert cex.step == 150 and set(cex.initial) == {"p", "v", "r"}
    replay = verified_loop(loop, kwargs).simulate(np.array([[cex.initial[s] for s in res.states]]), 150)[0]
    # Batched and single-row float evaluation may round differently (BLAS): equal to 1e-9.
    np.testing.assert_allclose(np.asarray(cex.trajectory), replay, rtol=1e-9, atol=1e-12)
    assert replay[:, 0].max() < 0.45  # never at the goal: the violation replays


def test_the_oracle_catches_a_box_that_misses_a_run():
    target, kwargs = CASES["mc_goal"]()
    res = pv.verify(target, progress=False, **kwargs)
    cell = res.cells[0]
    lo, hi = cell.boxes[50][0]
    cell.boxes[50][0] = (lo + 0.25 * (hi - lo), hi)  # drop a quarter of p's range at step 50
    with pytest.raises(AssertionError, match="outside the reach boxes"):
        check_against_simulation(target, kwargs, res)
    # And a verified cell whose sampled runs break the property (here one the engine was not given).
    good = pv.verify(target, progress=False, **kwargs)
    p = pv.variables("p")
    with pytest.raises(AssertionError, match="a sampled run is unsafe"):
        check_against_simulation(target, {**kwargs, "safe": p <= 0.3}, good, n=50)
