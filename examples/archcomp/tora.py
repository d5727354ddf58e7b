"""ARCH-COMP AINNCS TORA (JuliaReach models/TORA/TORA.jl): a cart on a spring moved by a rotating
arm. ``relu``: controllerTora.mat, u = N(x) - 10, period 1, stay in [-2, 2]^4 for 20 s.
``relutanh`` / ``sigmoid``: u = 11 N(x), period 0.5, reach x1 in [-0.1, 0.2], x2 in [-0.9, -0.6]
at t = 5."""

import percver as pv
from _common import main, network

# Variant -> the verdict JuliaReach asserts.
VARIANTS = {"relu": "verified", "relutanh": "verified", "sigmoid": "verified"}


def problem(variant: str = "relu"):
    x1, x2, x3, x4, u = pv.variables("x1 x2 x3 x4 u")
    rhs = {x1: x2, x2: -x1 + 0.1 * pv.sin(x3), x3: x4, x4: u}
    states = ["x1", "x2", "x3", "x4"]
    if variant == "relu":
        plant = pv.Continuous(rhs, inputs=[u], period=1.0)
        stage = pv.Stage(network("TORA", "controllerTora.mat"), inputs=states, output="u", offset=-10.0)
        init = {"x1": (0.6, 0.7), "x2": (-0.7, -0.6), "x3": (-0.4, -0.3), "x4": (0.5, 0.6)}
        box = pv.Box({s: (-2.0, 2.0) for s in states})
        # JuliaReach's grid, 4 x 4 x 3 x 5 (240 cells). Without state symbols the enclosure grows
        # about 3x per period from any cell size (the controller's correction of an earlier error
        # does not cancel it), and no cell gets past period 10.
        return pv.ClosedLoop(plant, [stage]), dict(
            init=init, steps=20, safe=box, split={"x1": 4, "x2": 4, "x3": 3, "x4": 5}, order=3, max_splits=16, state_symbols=True
        )
    file = {"relutanh": "nn_tora_relu_tanh.mat", "sigmoid": "nn_tora_sigmoid.mat"}[variant]
    plant = pv.Continuous(rhs, inputs=[u], period=0.5)
    stage = pv.Stage(network("TORA", file), inputs=states, output="u", scale=11.0)
    init = {"x1": (-0.77, -0.75), "x2": (-0.45, -0.43), "x3": (0.51, 0.54), "x4": (-0.3, -0.28)}
    goal = pv.Box({"x1": (-0.1, 0.2), "x2": (-0.9, -0.6)})
    return pv.ClosedLoop(plant, [stage]), dict(init=init, steps=10, goal=goal, order=4, max_splits=16)


if __name__ == "__main__":
    import sys

    variant = sys.argv[1] if len(sys.argv) > 1 else "relu"
    main(problem, VARIANTS[variant], variant=variant)
