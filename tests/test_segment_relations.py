"""Safety between the control steps is decided on the flowpipe segments' Taylor models where their
boxes fail: a relation between states (a speed limit that grows with the distance) holds on the
models where the box, which drops how the states move together, breaks it. Checked against scipy
runs sampled densely in time: proved only where every run keeps it."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv

INIT = {"x": (0.9, 1.1), "y": (-0.1, 0.1)}


def half_turn() -> pv.ClosedLoop:
    """x' = y, y' = -x over one period of pi: half a turn about the origin."""
    x, y = pv.variables("x y")
    return pv.ClosedLoop(pv.Continuous({x: y, y: -x}, period=np.pi), [])


def peak() -> float:
    """The largest 0.5 x^2 + y^2 that runs from the initial box reach (scipy, 2,001 times each)."""
    rng = np.random.default_rng(0)
    corners = np.array(np.meshgrid(*INIT.values())).reshape(2, -1).T
    inner = np.column_stack([rng.uniform(lo, hi, 200) for lo, hi in INIT.values()])
    t = np.linspace(0.0, np.pi, 2001)
    best = 0.0
    for x0 in np.vstack([corners, inner]):
        run = solve_ivp(lambda _t, s: [s[1], -s[0]], (0.0, np.pi), x0, t_eval=t, rtol=1e-10, atol=1e-12).y
        best = max(best, float(np.max(0.5 * run[0] ** 2 + run[1] ** 2)))
    return best


@pytest.mark.parametrize("limit, verdict", [(1.3, "verified"), (1.2, "unknown")])
def test_a_relation_is_proved_between_steps_only_where_runs_keep_it(limit, verdict):
    x, y = pv.variables("x y")
    assert 1.2 < peak() < 1.3  # crossed inside the period only: 0.615 at most at both of its ends
    # One cell (pv.Grid): the relation is decided on its flowpipe, and an adaptive default would
    # halve the unknown cell along the crossing's boundary down to its floor (300 s in CI).
    result = pv.verify(
        half_turn(), INIT, steps=1, safe=0.5 * x**2 + y**2 <= limit, order=4, max_splits=0, falsify=0, splitter=pv.Grid({}), progress=False
    )
    assert len(result.cells) == 1
    assert result.verdict == verdict, result.cells[0].reason
