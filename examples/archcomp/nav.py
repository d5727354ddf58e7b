"""ARCH-COMP AINNCS NAV (JuliaReach models/NAV, the set-based trained controller nn-nav-set.mat):
a robot (x1, x2) with speed x3 and heading x4, period 0.2; be in [-0.5, 0.5]^2 at t = 6 and never
in the obstacle [1, 2]^2 (reach-avoid)."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}


def problem(variant: str = ""):
    x1, x2, x3, x4 = pv.variables("x1 x2 x3 x4")
    u1, u2 = pv.variables("u_0 u_1")
    plant = pv.Continuous({x1: x3 * pv.cos(x4), x2: x3 * pv.sin(x4), x3: u1, x4: u2}, inputs=["u"], period=0.2)
    stage = pv.Stage(network("NAV", "nn-nav-set.mat"), inputs=["x1", "x2", "x3", "x4"], output="u")
    init = {"x1": (2.9, 3.1), "x2": (2.9, 3.1), "x3": (0.0, 0.0), "x4": (0.0, 0.0)}
    goal = pv.Box({"x1": (-0.5, 0.5), "x2": (-0.5, 0.5)})
    obstacle = pv.Box({"x1": (1.0, 2.0), "x2": (1.0, 2.0)})
    return pv.ClosedLoop(plant, [stage]), dict(
        init=init, steps=30, goal=goal, unsafe=obstacle, split={"x1": 2, "x2": 2}, order=3, max_splits=16
    )


if __name__ == "__main__":
    main(problem, VARIANTS[""])
