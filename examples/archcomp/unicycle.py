"""ARCH-COMP AINNCS unicycle (JuliaReach models/Unicycle): position, heading x3 and speed x4, a
constant unknown disturbance w in [-1e-4, 1e-4] on x4', a ReLU controller (controllerB_nnv.mat)
with u = N(x) - 20, period 0.2; reach a box around the origin at t = 10."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}


def problem(variant: str = ""):
    x1, x2, x3, x4, w = pv.variables("x1 x2 x3 x4 w")
    u1, u2 = pv.variables("u_0 u_1")
    rhs = {x1: x4 * pv.cos(x3), x2: x4 * pv.sin(x3), x3: u2, x4: u1 + w, w: 0.0 * w}
    plant = pv.Continuous(rhs, inputs=["u"], period=0.2)
    stage = pv.Stage(network("Unicycle", "controllerB_nnv.mat"), inputs=["x1", "x2", "x3", "x4"], output="u", offset=-20.0)
    init = {"x1": (9.5, 9.55), "x2": (-4.5, -4.45), "x3": (2.1, 2.11), "x4": (1.5, 1.51), "w": (-1e-4, 1e-4)}
    goal = pv.Box({"x1": (-0.6, 0.6), "x2": (-0.2, 0.2), "x3": (-0.06, 0.06), "x4": (-0.3, 0.3)})
    # JuliaReach's grid 3 x 1 x 7 x 1 with x2 in 4 (84 cells) and state symbols: on JuliaReach's
    # cells the controller's ReLU relaxation errors grow ~1.6x a period from step 20 and x3 blows
    # up in the last periods even with 16 in-cell splits (bench/README.md, ARCH-COMP).
    settings = dict(split={"x1": 3, "x2": 4, "x3": 7}, order=3, max_splits=16, state_symbols=True)
    return pv.ClosedLoop(plant, [stage]), dict(init=init, steps=50, goal=goal, **settings)


if __name__ == "__main__":
    main(problem, VARIANTS[""])
