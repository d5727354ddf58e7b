"""The workflow of examples/measure_diagnose_verify.py end to end on small data: the textbook
model verified, the hidden effects named, the diagnosed model falsified with a counterexample
that replays on the data generator, a start set verified inside the validated domain, and from the
valley floor verified with the parameters held over a run, unknown with them re-drawn; and the
negative control (no hidden effect: nothing claimed, the same verdict as the textbook)."""

import sys
from pathlib import Path

import numpy as np

import percver as pv

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import measure_diagnose_verify as example  # noqa: E402


def test_measure_diagnose_verify():
    textbook, diagnosis, falsified, fixed, (held, redrawn) = example.main(quick=True)
    assert textbook.verdict == "verified"
    assert sorted(diagnosis.effects) == ["actuator_gain", "coulomb_friction"]
    assert falsified.verdict == "falsified"
    cex = falsified.counterexample
    assert not example.replay(cex)  # the real car from that start never reaches the goal
    # The counterexample is a run of the diagnosed loop with the parameters it carries.
    plant = diagnosis.system(uncertainty="ci95", draws=20)
    loop = example.loop(plant, example.gentle())
    run = loop.simulate(np.array([[cex.initial["p"], cex.initial["v"]]]), example.STEPS, parameters=cex.parameter_values())
    np.testing.assert_allclose(run[0], np.asarray(cex.trajectory)[: len(run[0])], atol=1e-12)
    assert run[0, :, 0].max() < 0.45
    assert fixed.verdict == "verified" and fixed.validity.startswith("verified inside the validated domain")
    # From the valley floor: verified with the parameters held over a run, not when they are re-drawn every step.
    assert held.verdict == "verified" and redrawn.verdict == "unknown"


def test_no_hidden_effect_claims_nothing_and_verifies_like_the_textbook():
    data = example.measure(runs=12, steps=80, seed=3, friction=0.0, gain=1.0)
    diagnosis = pv.diagnose(example.textbook(), data, effects=["coulomb_friction", "actuator_gain", "linear_drag"])
    assert diagnosis.steps == [] and diagnosis.unexplained == []
    textbook = example.reach_goal(example.loop(example.textbook(), example.gentle()))
    diagnosed = example.reach_goal(example.loop(diagnosis.model, example.gentle()))
    assert diagnosed.verdict == textbook.verdict == "verified"
    cells = {str(sorted(c.box.items())): c.boxes for c in textbook.cells}
    assert {str(sorted(c.box.items())): c.boxes for c in diagnosed.cells} == cells  # the same reach sets
