"""ARCH-COMP AINNCS attitude control (JuliaReach models/AttitudeControl): a rigid body's angular
velocity and Rodrigues parameters, a sigmoid controller (model.mat), period 0.1; avoid a box of
states for 3 s."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}


def problem(variant: str = ""):
    w1, w2, w3, p1, p2, p3 = pv.variables("w1 w2 w3 p1 p2 p3")
    u0, u1, u2 = pv.variables("u_0 u_1 u_2")
    xi = p1**2 + p2**2 + p3**2
    rhs = {
        w1: 0.25 * (u0 + w2 * w3),
        w2: 0.5 * (u1 - 3.0 * w1 * w3),
        w3: u2 + 2.0 * w1 * w2,
        p1: 0.5 * (w2 * (xi - p3) + w3 * (xi + p2) + w1 * (xi + 1.0)),
        p2: 0.5 * (w1 * (xi + p3) + w3 * (xi - p1) + w2 * (xi + 1.0)),
        p3: 0.5 * (w1 * (xi - p2) + w2 * (xi + p1) + w3 * (xi + 1.0)),
    }
    states = ["w1", "w2", "w3", "p1", "p2", "p3"]
    plant = pv.Continuous(rhs, inputs=["u"], period=0.1)
    stage = pv.Stage(network("AttitudeControl", "model.mat"), inputs=states, output="u")
    lo, hi = [-0.45, -0.55, 0.65, -0.75, 0.85, -0.65], [-0.44, -0.54, 0.66, -0.74, 0.86, -0.64]
    unsafe = pv.Box(dict(zip(states, [(-0.2, 0.0), (-0.5, -0.4), (0.0, 0.2), (-0.7, -0.6), (0.7, 0.8), (-0.4, -0.2)])))
    return pv.ClosedLoop(plant, [stage]), dict(init=dict(zip(states, zip(lo, hi))), steps=30, unsafe=unsafe, order=4, max_splits=16)


if __name__ == "__main__":
    main(problem, VARIANTS[""])
