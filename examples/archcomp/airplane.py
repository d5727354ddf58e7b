"""ARCH-COMP AINNCS airplane (JuliaReach models/Airplane): 12 states (position, velocity, Euler
angles, body rates), a ReLU controller of 6 forces and moments, period 0.1; s_y and the three
angles must stay in [-1, 1] for 20 periods (JuliaReach: falsified, from the top corner)."""

import percver as pv
from _common import main, network

VARIANTS = {"": "falsified"}
STATES = ["s_x", "s_y", "s_z", "v_x", "v_y", "v_z", "phi", "theta", "psi", "r", "p", "q"]


def matmul(a, b):
    return [[sum((a[i][k] * b[k][j] for k in range(len(b))), 0.0) for j in range(len(b[0]))] for i in range(len(a))]


def problem(variant: str = ""):
    sx, sy, sz, vx, vy, vz, phi, theta, psi, r, p, q = pv.variables(" ".join(STATES))
    Fx, Fy, Fz, Mx, My, Mz = pv.variables("u_0 u_1 u_2 u_3 u_4 u_5")
    c, s = pv.cos, pv.sin
    t_psi = [[c(psi), -s(psi), 0.0], [s(psi), c(psi), 0.0], [0.0, 0.0, 1.0]]
    t_theta = [[c(theta), 0.0, s(theta)], [0.0, 1.0, 0.0], [-s(theta), 0.0, c(theta)]]
    t_phi = [[1.0, 0.0, 0.0], [0.0, c(phi), -s(phi)], [0.0, s(phi), c(phi)]]
    xyz = matmul(matmul(matmul(t_psi, t_theta), t_phi), [[vx], [vy], [vz]])
    # JuliaReach's R(phi, theta), including its cos(theta) in the middle row.
    rates = matmul(
        [[1.0, pv.tan(theta) * s(phi), pv.tan(theta) * c(phi)], [0.0, c(theta), -s(phi)], [0.0, s(phi) / c(theta), c(phi) / c(theta)]],
        [[p], [q], [r]],
    )
    rhs = {
        sx: xyz[0][0],
        sy: xyz[1][0],
        sz: xyz[2][0],
        vx: -s(theta) + Fx - q * vz + r * vy,
        vy: c(theta) * s(phi) + Fy - r * vx + p * vz,
        vz: c(theta) * c(phi) + Fz - p * vy + q * vx,
        phi: rates[0][0],
        theta: rates[1][0],
        psi: rates[2][0],
        r: Mz,
        p: Mx,
        q: My,
    }
    plant = pv.Continuous(rhs, inputs=["u"], period=0.1)
    stage = pv.Stage(network("Airplane", "controller_airplane.nnet"), inputs=STATES, output="u")
    init = {name: (0.0, 1.0) if name in ("v_x", "v_y", "v_z", "phi", "theta", "psi") else (0.0, 0.0) for name in STATES}
    safe = pv.Box({name: (-1.0, 1.0) for name in ("s_y", "phi", "theta", "psi")})
    return pv.ClosedLoop(plant, [stage]), dict(init=init, steps=20, safe=safe, order=3, max_splits=0)


if __name__ == "__main__":
    main(problem, VARIANTS[""])
