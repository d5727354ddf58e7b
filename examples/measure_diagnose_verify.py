"""From measurements to a proof: Mountain Car whose real car has Coulomb friction and a weak motor.

1. Measure: runs of the "real" car (a plain numpy simulator with a dry friction of 0.0004 per
   step and a motor delivering 90% of the commanded force) under random thrust.
2. The textbook model (the paper's Appendix A.1, with the left wall) and a gentle controller
   u = clip(200 v, -1, 1): verified, every start in the valley reaches the goal.
3. ``pv.diagnose`` names the missing effects (coulomb_friction, actuator_gain) and fits them.
4. The diagnosed model, with every parameter in its 95% confidence interval: falsified. The
   counterexample replays in the real car's simulator: the car never reaches the goal.
5. What the diagnosed car can do: pushing at full thrust along the motion from a start high on
   the left hill, it verifies for every parameter in the intervals, and its reach sets stay
   inside the domain the measurements cover. From the valley floor it verifies too, because the
   parameters are constants of the car, held over a run (``per="run"``, the default of
   ``diagnosis.system``); taken as new values every step (``per="step"``) they spread the
   arrival too much: unknown.

    python examples/measure_diagnose_verify.py [--quick]
"""

from __future__ import annotations

import sys

import numpy as np

import percver as pv

FRICTION, GAIN = 0.0004, 0.9
INIT = {"p": (-0.50, -0.48), "v": (0.0, 0.0)}  # at rest at the valley floor
HILL = {"p": (-1.0, -0.98), "v": (0.0, 0.002)}  # at rest high on the left hill
STEPS = 200


def real_car(states, controls, friction=FRICTION, gain=GAIN):
    """The real car, one step for rows of (p, v) and thrust u: written without percver."""
    p, v = states[:, 0], states[:, 1]
    v = np.sign(v) * np.maximum(np.abs(v) - friction, 0.0)
    v = np.clip(v + 0.0015 * gain * controls[:, 0] - 0.0025 * np.cos(3 * p), -0.07, 0.07)
    p = p + v
    wall = p < -1.2
    return np.column_stack([np.where(wall, -1.2, p), np.where(wall, 0.0, v)])


def measure(runs: int, steps: int, seed: int = 0, **car) -> pv.Measurements:
    """Runs of the real car (``car``: its friction and gain) under random piecewise-constant
    thrust, positions and speeds measured with a small noise (1e-5)."""
    rng = np.random.default_rng(seed)
    rows, controls, trajectory, time = [], [], [], []
    for run in range(runs):
        state = np.array([[rng.uniform(-1.2, 0.5), rng.uniform(-0.07, 0.07)]])
        thrust = np.repeat(rng.uniform(-1, 1, steps), rng.integers(2, 8, steps))[:steps]
        for k in range(steps):
            rows.append(state[0] + rng.normal(0, 1e-5, 2))
            controls.append([thrust[k]])
            trajectory.append(run)
            time.append(float(k))
            state = real_car(state, np.array([[thrust[k]]]), **car)
    return pv.Measurements(
        np.array(rows),
        controls=np.array(controls),
        trajectory=np.array(trajectory),
        time=np.array(time),
        state_names=["p", "v"],
        control_names=["u"],
    )


def textbook():
    """The textbook plant as expressions, with the left wall that stops the car."""
    p, v, u = pv.variables("p v u")
    v1 = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    wall = p + v1 < -1.2
    return pv.Discrete({p: pv.where(wall, -1.2, p + v1), v: pv.where(wall, 0.0, v1)}, inputs=[u])


def loop(plant, controller):
    p, v = pv.variables("p v")
    return pv.ClosedLoop(plant, stages=[pv.Stage(controller, inputs=[p, v], output="u")])


def gentle():
    """Thrust proportional to the speed near rest: too weak to overcome dry friction there."""
    return pv.clip(200 * pv.variables("v"), -1.0, 1.0)


def full_thrust():
    """Full thrust along the motion, and to the right at rest (where gentle thrust is nothing)."""
    return pv.where(pv.variables("v") >= 0.0, 1.0, -1.0)


def reach_goal(the_loop, init=INIT):
    """Every start reaches p >= 0.45 within STEPS steps? (A diagnosed plant carries its validated
    domain, so the result's ``validity`` says whether the reach sets stay inside it.)"""
    p = pv.variables("p")
    return pv.verify(the_loop, init=init, steps=STEPS, goal=p >= 0.45, within=True, split={"p": 4}, refine=True, progress=False)


def replay(counterexample):
    """The counterexample's start on the real car with the gentle controller: reached the goal?"""
    state = np.array([[counterexample.initial["p"], counterexample.initial["v"]]])
    for _ in range(STEPS):
        state = real_car(state, np.clip(200 * state[:, 1:2], -1, 1))
        if state[0, 0] >= 0.45:
            return True
    return False


def main(quick: bool = False):
    data = measure(runs=20 if quick else 100, steps=100 if quick else 200)
    print(f"measured {len(data)} rows of {data.trajectory.max() + 1} runs")

    textbook_result = reach_goal(loop(textbook(), gentle()))
    print(f"textbook model, gentle controller: {textbook_result.verdict}")

    diagnosis = pv.diagnose(textbook(), data, effects=["coulomb_friction", "actuator_gain", "linear_drag", "actuator_bias"])
    print(diagnosis.table())
    draws = 20 if quick else 100
    for i, ranges in diagnosis.intervals(0.95, draws=draws).items():
        effect = diagnosis.final_model.effects[i]
        for name, (lo, hi) in ranges.items():
            print(f"  {effect.name}.{name} = {effect.params[name]:.6g}, 95% interval [{lo:.6g}, {hi:.6g}]")

    plant = diagnosis.system(uncertainty="ci95", draws=draws)
    print(plant.validation)
    falsified = reach_goal(loop(plant, gentle()))
    cex = falsified.counterexample
    print(f"diagnosed model, gentle controller: {falsified.verdict}")
    if cex is not None:
        print(
            f"  counterexample from p0 = {cex.initial['p']:.5f}: {cex.violated}; "
            f"on the real car it {'reaches' if replay(cex) else 'never reaches'} the goal in {STEPS} steps"
        )
    print(f"  {falsified.validity}")

    fixed = reach_goal(loop(plant, full_thrust()), HILL)
    print(f"diagnosed model, full thrust along the motion from p0 in {HILL['p']}: {fixed.verdict}; {fixed.validity}")
    held = reach_goal(loop(plant, full_thrust()))
    redrawn = reach_goal(loop(diagnosis.system(uncertainty="ci95", draws=draws, per="step"), full_thrust()))
    print(f"  and from p0 in {INIT['p']}: {held.verdict} (parameters held over a run), {redrawn.verdict} (re-drawn every step)")
    return textbook_result, diagnosis, falsified, fixed, (held, redrawn)


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
