"""ARCH-COMP AINNCS single inverted pendulum (JuliaReach models/InvertedPendulum): theta'' =
2 sin(theta) + 8 T (m = L = 0.5, g = 1, no friction), ReLU controller, period 0.05; theta must be
in [0, 1] for t in [0.5, 1]."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}


def problem(variant: str = ""):
    theta, omega, T = pv.variables("theta omega T")
    plant = pv.Continuous({theta: omega, omega: 2.0 * pv.sin(theta) + 8.0 * T}, inputs=[T], period=0.05)
    stage = pv.Stage(network("InvertedPendulum", "controller_single_pendulum.nnet"), inputs=["theta", "omega"], output="T")
    window = pv.during(pv.Box({"theta": (0.0, 1.0)}), time=(0.5, 1.0))
    # JuliaReach splits theta at 1.1, 1.16 and omega at 0.09, 0.145, 0.18 (3 x 4 cells).
    return pv.ClosedLoop(plant, [stage]), dict(
        init={"theta": (1.0, 1.175), "omega": (0.0, 0.2)}, steps=20, safe=window, split={"theta": 3, "omega": 4}, order=4, max_splits=16
    )


if __name__ == "__main__":
    main(problem, VARIANTS[""])
