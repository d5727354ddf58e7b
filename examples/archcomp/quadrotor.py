"""ARCH-COMP AINNCS quadrotor (JuliaReach models/Quadrotor, the small initial set: 1% of the
original radius): 12 states, a sigmoid controller of 3 torques, period 0.1; the altitude x3 must
be in [0.94, 1.06] at t = 5."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}
STATES = [f"x{i}" for i in range(1, 13)]


def problem(variant: str = ""):
    x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12 = pv.variables(" ".join(STATES))
    u1, u2, u3 = pv.variables("u_0 u_1 u_2")
    g, m, jx, jy = 9.81, 1.4, 0.054, 0.054
    s7, c7, s8, c8, s9, c9 = pv.sin(x7), pv.cos(x7), pv.sin(x8), pv.cos(x8), pv.sin(x9), pv.cos(x9)
    yaw_rate = s7 / c8 * x11
    rhs = {
        x1: c9 * c8 * x4 + (s7 * c9 * s8 - c7 * s9) * x5 + (c7 * c9 * s8 + s7 * s9) * x6,
        x2: s9 * c8 * x4 + (s7 * s9 * s8 + c7 * c9) * x5 + (c7 * s9 * s8 - s7 * c9) * x6,
        x3: s8 * x4 - s7 * c8 * x5 - c7 * c8 * x6,
        x4: -x11 * x6 - g * s8,
        x5: x10 * x6 + g * s7 * c8,
        x6: x11 * x4 - x10 * x5 + g * c7 * c8 - (g + u1 / m),
        x7: x10 + s8 * yaw_rate,
        x8: c7 * x11,
        x9: yaw_rate,
        x10: u2 / jx,
        x11: u3 / jy,
        x12: 0.0 * x12,
    }
    plant = pv.Continuous(rhs, inputs=["u"], period=0.1)
    stage = pv.Stage(network("Quadrotor", "model.mat"), inputs=STATES, output="u")
    init = {name: (-0.004, 0.004) if i < 6 else (0.0, 0.0) for i, name in enumerate(STATES)}
    # State symbols: without them the pitch x8's enclosure wraps until 1/cos(x8) is undefined (step 19).
    return pv.ClosedLoop(plant, [stage]), dict(
        init=init, steps=50, goal=pv.Box({"x3": (0.94, 1.06)}), order=3, max_splits=16, state_symbols=True
    )


if __name__ == "__main__":
    main(problem, VARIANTS[""])
