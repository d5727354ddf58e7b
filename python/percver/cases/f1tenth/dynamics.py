"""The F1/10 car: the bicycle model of the paper's Appendix B.1 (identified in HSCC'20).

    x' = v cos(theta)    y' = v sin(theta)
    v' = -c_a v + c_a c_m (u - c_h)        (throttle u = 16: steady speed 2.4 m/s)
    theta' = v tan(delta) / (l_f + l_r)

States are ``(x, y, theta, v)`` so that the first three columns are the LiDAR pose. The
steering delta (radians) is held for each 0.1 s control period and integrated with fixed-step
RK4 inside it. ``equations`` gives the same vector field as expressions, in world or in
hallway-local coordinates, for flowpipes.
"""

from __future__ import annotations

import numpy as np

from percver.errors import InputError

THROTTLE = 16.0
C_A = 1.633
C_M = 0.2
C_H = 4.0
L_F = 0.225
L_R = 0.225
MAX_STEERING = np.radians(15.0)
PERIOD = 0.1
STATE_NAMES = ("x", "y", "theta", "v")
# RK4 steps per second: 0.005 s steps keep the integration error below 1e-9 m over a run.
STEPS_PER_SECOND = 200


def derivative(states, delta) -> np.ndarray:
    """The vector field at states (N x 4) under steering ``delta`` (N,) radians."""
    x, y, theta, v = np.asarray(states, dtype=float).T
    return np.column_stack([v * np.cos(theta), v * np.sin(theta), v * np.tan(delta) / (L_F + L_R), -C_A * v + C_A * C_M * (THROTTLE - C_H)])


def integrate(states, delta, duration: float) -> np.ndarray:
    """States after ``duration`` seconds with the steering held (RK4, ``STEPS_PER_SECOND``)."""
    states = np.atleast_2d(np.asarray(states, dtype=float))
    if states.shape[1] != 4:
        raise InputError(f"F1/10 states are (x, y, theta, v): need 4 columns, got {states.shape[1]}")
    delta = np.broadcast_to(np.clip(np.asarray(delta, dtype=float), -MAX_STEERING, MAX_STEERING), states.shape[:1])
    steps = max(1, int(np.ceil(duration * STEPS_PER_SECOND - 1e-9)))
    h = duration / steps
    for _ in range(steps):
        k1 = derivative(states, delta)
        k2 = derivative(states + h / 2 * k1, delta)
        k3 = derivative(states + h / 2 * k2, delta)
        k4 = derivative(states + h * k3, delta)
        states = states + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return states


def step(states, delta) -> np.ndarray:
    """One 0.1 s control period."""
    return integrate(states, delta, PERIOD)


def equations(frame: str = "world", delta="delta") -> dict:
    """The vector field as ``{name: Expr}``; ``delta`` is a steering variable (or its name).

    ``frame="world"``: states x, y, theta, v. ``frame="local"``: the verification models'
    y1 (distance to the left wall), y2 (to the front wall), y3 (speed), y4 (relative heading),
    with y1' = -y3 sin(y4) and y2' = -y3 cos(y4).
    """
    from percver import expr as px

    delta = px.Expr.var(delta) if isinstance(delta, str) else delta
    accel = C_A * C_M * (THROTTLE - C_H)
    turn = px.tan(delta) / (L_F + L_R)
    if frame == "world":
        x, y, theta, v = px.variables("x y theta v")
        return {"x": v * px.cos(theta), "y": v * px.sin(theta), "theta": v * turn, "v": accel - C_A * v}
    if frame == "local":
        y1, y2, y3, y4 = px.variables("y1 y2 y3 y4")
        return {"y1": -y3 * px.sin(y4), "y2": -y3 * px.cos(y4), "y3": accel - C_A * y3, "y4": y3 * turn}
    raise InputError(f"unknown frame '{frame}': use 'world' or 'local'")
