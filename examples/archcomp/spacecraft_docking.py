"""ARCH-COMP AINNCS spacecraft docking (JuliaReach models/SpacecraftDocking, the smaller initial
set): Clohessy-Wiltshire relative motion, a tanh controller (model.mat, with its linear pre- and
post-processing layers), period 1; the speed must stay below 0.2 + 2 n |position| for 40 s."""

import percver as pv
from _common import main, network

VARIANTS = {"": "verified"}
N = 0.001027  # mean motion


def problem(variant: str = ""):
    sx, sy, vx, vy = pv.variables("s_x s_y v_x v_y")
    fx, fy = pv.variables("F_0 F_1")
    rhs = {sx: vx, sy: vy, vx: 3 * N**2 * sx + 2 * N * vy + fx / 12.0, vy: -2 * N * vx + fy / 12.0}
    plant = pv.Continuous(rhs, inputs=["F"], period=1.0)
    stage = pv.Stage(network("SpacecraftDocking", "model.mat"), inputs=["s_x", "s_y", "v_x", "v_y"], output="F")
    init = {"s_x": (70, 106), "s_y": (70, 106), "v_x": (-0.14, 0.14), "v_y": (-0.14, 0.14)}
    safe = pv.sqrt(vx**2 + vy**2) <= 0.2 + 2 * N * pv.sqrt(sx**2 + sy**2)
    # The controller holds the speed 0.044 under the limit for the whole run, so the enclosures
    # must stay within a few hundredths of the sampled speeds for 40 periods. Restarting a part
    # from its box (rebox) verifies every cell of this grid (at most 58 splits); state symbols
    # lose it: their parallelotope grows the positions' symbols 1.3-2x a period (bench/README.md).
    return pv.ClosedLoop(plant, [stage]), dict(
        init=init,
        steps=40,
        safe=safe,
        split={"s_x": 4, "s_y": 4, "v_x": 2, "v_y": 2},
        order=3,
        max_splits=64,
        rebox=True,
    )


if __name__ == "__main__":
    main(problem, VARIANTS[""])
