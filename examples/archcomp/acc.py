"""ARCH-COMP AINNCS adaptive cruise control (JuliaReach models/ACC): a lead car braking at
a_lead = -2 and an ego car whose acceleration is set by a network from (v_set = 30, T_gap = 1.4,
v_ego, D_rel, v_rel); keep x_lead - x_ego - 1.4 v_ego >= 10 for 5 s (period 0.1). Controllers:
``relu`` (controller_5_20.mat) and ``tanh`` (tanh.yml)."""

import percver as pv
from _common import main, network

VARIANTS = {"relu": "verified", "tanh": "verified"}


def problem(variant: str = "relu"):
    xl, vl, gl, xe, ve, ge, a = pv.variables("x_lead v_lead g_lead x_ego v_ego g_ego a_ego")
    rhs = {xl: vl, vl: gl, gl: 2.0 * (-2.0 - gl) - 0.0001 * vl**2, xe: ve, ve: ge, ge: 2.0 * (a - ge) - 0.0001 * ve**2}
    plant = pv.Continuous(rhs, inputs=[a], period=0.1)
    file = {"relu": "controller_5_20.mat", "tanh": "tanh.yml"}[variant]
    relative = pv.Stage([xl - xe, vl - ve], inputs=["x_lead", "x_ego", "v_lead", "v_ego"], output="rel")
    control = pv.Stage(network("ACC", file), inputs=[30.0, 1.4, "v_ego", "rel"], output="a_ego")
    init = {"x_lead": (90, 110), "v_lead": (32, 32.2), "g_lead": (0, 0), "x_ego": (10, 11), "v_ego": (30, 30.2), "g_ego": (0, 0)}
    return pv.ClosedLoop(plant, [relative, control]), dict(init=init, steps=50, safe=xl - xe - 1.4 * ve >= 10.0, order=3, max_splits=16)


if __name__ == "__main__":
    import sys

    variant = sys.argv[1] if len(sys.argv) > 1 else "relu"
    main(problem, VARIANTS[variant], variant=variant)
