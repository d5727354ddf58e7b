"""Validate a Mountain Car plant model against measured runs of a car that feels drag.

The model is the textbook step (Appendix A.1 of the paper). The "real" car also loses 1.5%
of its velocity to drag every step. percver compares one-step predictions with the runs,
names the missing drag term with its coefficient and shows the error fall.

    python examples/validate_dynamics.py [report-directory]
"""

import sys

import numpy as np

import percver as pv
from percver.validate import FunctionPlant

out = sys.argv[1] if len(sys.argv) > 1 else "validate-dynamics-report"


def mountain_car(states, controls, drag=0.0):
    p, v = states[:, 0], states[:, 1]
    v = np.clip(v * (1 - drag) + 0.0015 * controls[:, 0] - 0.0025 * np.cos(3 * p), -0.07, 0.07)
    p = p + v
    stopped = p < -1.2  # the left wall stops the car
    return np.column_stack([np.where(stopped, -1.2, p), np.where(stopped, 0.0, v)])


# ---- the "real" car: drag, plus small measurement noise, driven by an energy-pumping policy
rng = np.random.default_rng(0)
rows = {"states": [], "controls": [], "trajectory": [], "time": []}
for run in range(40):
    state = np.array([[rng.uniform(-0.6, -0.4), 0.0]])
    for k in range(80):
        u = np.clip(np.sign(state[0, 1]) + rng.normal(0, 0.5), -1, 1)  # push along the motion, jittered
        rows["states"].append(state[0] + rng.normal(0, 1e-5, 2))
        rows["controls"].append([u])
        rows["trajectory"].append(run)
        rows["time"].append(k)
        state = mountain_car(state, np.array([[u]]), drag=0.015)
data = pv.Measurements(
    np.array(rows["states"]),
    controls=np.array(rows["controls"]),
    trajectory=np.array(rows["trajectory"]),
    time=np.array(rows["time"], dtype=float),
    state_names=["p", "v"],
    control_names=["u"],
)

# ---- the model: the textbook plant, no drag
plant = FunctionPlant(mountain_car, ["p", "v"], ["u"], velocity_names=["v"])
report = pv.compare(plant, data)
print(f"textbook plant: one-step RMSE {report.error:.3g} (per-dimension, in units of each state's step spread)")
print(report.where().table(rows=3), "\n")

diagnosis = pv.diagnose(plant, data)
print(diagnosis.rankings[0].table(), "\n")
print(diagnosis.table())
print(f"\nreport: {diagnosis.to_html(out)}")
