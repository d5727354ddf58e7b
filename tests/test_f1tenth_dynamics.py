"""F1/10 bicycle model: steady speed, straight and circular motion, the Expr vector field, the loop."""

import numpy as np
import pytest

import percver as pv
from percver.cases.f1tenth import dynamics, loop, world
from percver.errors import InputError

STEADY = dynamics.C_M * (dynamics.THROTTLE - dynamics.C_H)  # v' = 0 at c_m (u - c_h) = 2.4 m/s


def test_speed_approaches_steady_state_from_rest():
    assert STEADY == pytest.approx(2.4)
    state = np.array([[0.0, 0.0, 0.0, 0.0]])
    after = dynamics.integrate(state, 0.0, 1.0)
    # v(t) = 2.4 (1 - exp(-c_a t)); x(t) = 2.4 (t - (1 - exp(-c_a t)) / c_a)
    assert after[0, 3] == pytest.approx(STEADY * (1 - np.exp(-dynamics.C_A)), abs=1e-9)
    assert after[0, 0] == pytest.approx(STEADY * (1 - (1 - np.exp(-dynamics.C_A)) / dynamics.C_A), abs=1e-9)
    assert after[0, 1] == pytest.approx(0.0) and after[0, 2] == pytest.approx(0.0)


def test_circle_at_steady_speed_and_steering_clip():
    delta = np.radians(10.0)
    radius = (dynamics.L_F + dynamics.L_R) / np.tan(delta)
    state = np.array([[0.0, 0.0, 0.0, STEADY]])
    period = 2 * np.pi * radius / STEADY
    back = dynamics.integrate(state, delta, period)
    assert np.allclose(back[0, :2], [0.0, 0.0], atol=1e-7)
    assert (back[0, 2] - 2 * np.pi) == pytest.approx(0.0, abs=1e-9)
    # Steering beyond 15 degrees acts as 15 degrees.
    assert np.allclose(dynamics.step(state, 1.0), dynamics.step(state, dynamics.MAX_STEERING))
    with pytest.raises(InputError, match="4 columns"):
        dynamics.integrate(np.zeros((1, 3)), 0.0, 0.1)


def test_expr_vector_field_matches_numpy_in_both_frames():
    rng = np.random.default_rng(1)
    states = np.column_stack([rng.uniform(0, 20, 50), rng.uniform(0, 20, 50), rng.uniform(-3, 3, 50), rng.uniform(0, 3, 50)])
    delta = rng.uniform(-0.26, 0.26, 50)
    field = dynamics.equations("world")
    values = {"x": states[:, 0], "y": states[:, 1], "theta": states[:, 2], "v": states[:, 3], "delta": delta}
    got = pv.evaluate([field[k] for k in dynamics.STATE_NAMES], values)
    assert np.allclose(got, dynamics.derivative(states, delta), atol=1e-12)
    local = dynamics.equations("local")
    y = world.to_local(states)
    got = pv.evaluate(
        [local[k] for k in ("y1", "y2", "y3", "y4")], {"y1": y[:, 0], "y2": y[:, 1], "y3": states[:, 3], "y4": y[:, 2], "delta": delta}
    )
    d = dynamics.derivative(states, delta)
    assert np.allclose(got, np.column_stack([d[:, 0], -d[:, 1], d[:, 3], d[:, 2]]), atol=1e-12)
    with pytest.raises(InputError):
        dynamics.equations("polar")


def test_drive_stops_runs_on_crash_and_at_the_goal():
    track = world.square()
    lidar = world.controller_lidar()

    class Fixed:
        """Steers a constant angle (a stand-in for a controller network)."""

        def __init__(self, angle):
            self.angle, self.name = angle, f"fixed {angle}"

        def __call__(self, ranges):
            return np.full(len(ranges), self.angle)

    def sense(states, rng):
        scans = lidar.scan(track, states)
        return scans, scans

    starts = loop.StartBox(y4_deg=(0.0, 0.0)).sample(2, np.random.default_rng(0))
    runs = loop.drive(starts, [Fixed(0.0), Fixed(0.2)], sense, rate=40.0)
    assert runs.outcomes == ["crash", "crash"]  # straight into the front wall; left into the left wall
    ends = [world.to_local(runs.states[runs.rows(r)[-1]][None])[0] for r in (0, 1)]
    assert ends[0][1] < 0.5 and ends[1][0] < 0.5
    assert np.all(np.diff(runs.time[runs.rows(0)]) == pytest.approx(0.025))
    assert runs.safe_share() == {"fixed 0.0": 0.0, "fixed 0.2": 0.0}
    with pytest.raises(InputError, match="multiple"):
        loop.drive(starts, [Fixed(0.0)] * 2, sense, rate=15.0)
