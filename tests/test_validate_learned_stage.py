"""A learned noise model (diagnose(learn=True)) enters verification as network stages, the paper's
g_n: a knock-out classifier with one where() per dimension, or a generative network. Runs of the
exported ONNX file under onnxruntime, written here without percver's stages, stay inside the reach
sets; a counterexample replays on the hidden sensor."""

import functools

import numpy as np
import onnxruntime
import pytest

pytest.importorskip("torch")

import percver as pv  # noqa: E402
from percver.errors import InputError  # noqa: E402
from percver.validate.verifiable import LearnedSensor  # noqa: E402
from percver.verification import DomainWarning  # noqa: E402

x, u, y = pv.variables("x u y")
KNOCKED = (0.3, 0.5)  # where the hidden sensor reads -2 (a lost echo)
STEPS = 15
# Small networks, trained briefly on one thread (the machine is shared).
OPTIONS = {"knockout": {"threads": 1, "epochs": 150, "hidden": (16, 16)}, "generative": {"threads": 1, "epochs": 150, "hidden": (16,)}}


def hidden_sensor(states, kind, rng=None):
    """The real sensor of x: a knock-out region reading -2, or a smooth distortion for x > 0."""
    s = np.asarray(states, dtype=float)[:, 0]
    noise = 0.0 if rng is None else rng.normal(0, 0.002, len(s))
    if kind == "knockout":
        return np.where((s >= KNOCKED[0]) & (s <= KNOCKED[1]), -2.0, s + noise)
    return np.where(s > 0, s + 0.3 * np.sin(3 * s), s) + noise


@functools.lru_cache(maxsize=None)
def _diagnosis(kind):
    rng = np.random.default_rng(0)
    states = rng.uniform(-1, 1, (1200, 1))
    data = pv.Measurements(states, hidden_sensor(states, kind, rng)[:, None], state_names=["x"], measurement_names=["y"])
    return pv.diagnose([x], data, learn=kind, learn_options=OPTIONS[kind])


def _loop(sensor):
    """x' = x + 0.1 u with u = -0.5 y: the controller drives the measured x to 0."""
    return pv.ClosedLoop(
        pv.Discrete({x: x + 0.1 * u}, inputs=[u]), stages=[*sensor.stages(output="y"), pv.Stage(-0.5 * y, inputs=[y], output="u")]
    )


def _onnx_runs(path, sensor, x0, residual=None, seed=0):
    """Runs of the loop with the network from ``path`` under onnxruntime and the knock-out or the
    residual (drawn anew each step) written out in numpy."""
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    rng = np.random.default_rng(seed)
    runs = [np.asarray(x0, dtype=float)]
    for _ in range(STEPS):
        s = runs[-1]
        out = session.run(None, {name: np.column_stack([s, s])})[0][:, 0]
        if sensor.learned.kind == "knockout":
            model = sensor.learned.model
            out = np.where(out > model.thresholds[0], model.knocked[0], s)
        if residual:
            out = out + rng.uniform(-residual, residual, len(s))
        runs.append(s + 0.1 * (-0.5 * out))
    return np.stack(runs, axis=1)


def _inside(result, path, sensor, residual=None, per_cell=25):
    rng = np.random.default_rng(1)
    checked = 0
    for cell in result.cells:
        lo, hi = cell.box["x"]
        runs = _onnx_runs(path, sensor, rng.uniform(lo, hi, per_cell), residual)
        boxes = np.array(cell.boxes)[:, 0]
        assert len(boxes) == STEPS + 1
        assert np.all(runs >= boxes[:, 0] - 1e-9) and np.all(runs <= boxes[:, 1] + 1e-9)
        checked += len(runs)
    return checked


def test_learned_knockout_enters_as_a_classifier_stage_and_onnx_runs_stay_in_the_reach_sets(tmp_path):
    diagnosis = _diagnosis("knockout")
    assert diagnosis.effects == ["learned_knockout"]
    sensor = diagnosis.system(onnx=tmp_path)
    assert isinstance(sensor, LearnedSensor) and "network stage" in str(sensor.validation)
    path = tmp_path / "learned_knockout.onnx"
    loop = _loop(sensor)
    network = next(stage.component for stage in loop.stages if stage.is_network)
    assert network.source == path and network.domain[1][0] < -0.99 and network.domain[1][1] > 0.99
    # The chain is the diagnosed model: simulated with percver's stages, the runs equal onnxruntime's.
    x0 = np.linspace(-0.9, 0.9, 37)
    np.testing.assert_allclose(loop.simulate(x0[:, None], STEPS)[:, :, 0], _onnx_runs(path, sensor, x0), atol=1e-9)
    np.testing.assert_allclose(loop.stage_float(0, x0[:, None]), diagnosis.final_model.base.predict(x0[:, None]), atol=1e-12)
    verified = pv.verify(loop, init={"x": (0.3, 0.5)}, steps=STEPS, safe=x <= 0.7, split={"x": 0.01}, progress=False)
    assert verified.verdict == "verified"
    assert _inside(verified, path, sensor) == 500
    # Knocked out, the reading -2 pushes x up by 0.1: from the knock-out region it passes 0.55.
    falsified = pv.verify(loop, init={"x": (0.42, 0.48)}, steps=STEPS, safe=x <= 0.55, split={"x": 0.01}, progress=False)
    cex = falsified.counterexample
    assert falsified.verdict == "falsified"
    real = np.array([cex.initial["x"]])
    for _ in range(cex.step):
        real = real + 0.1 * (-0.5 * hidden_sensor(real[:, None], "knockout"))
    assert real[0] > 0.55  # the counterexample fails on the real sensor too


def test_learned_generative_enters_as_a_network_stage_with_the_residual_after_it(tmp_path):
    diagnosis = _diagnosis("generative")
    assert diagnosis.effects == ["learned_generative"]
    sensor = diagnosis.system(residual="max", onnx=tmp_path)
    bound = sensor.residual["y"]
    assert 0 < bound < 0.1  # the network leaves the noise and little more
    loop = _loop(sensor)
    assert [s.output for s in loop.stages] == ["y_canonical", "y_generated", "y", "u"]
    result = pv.verify(loop, init={"x": (-0.5, 0.6)}, steps=STEPS, safe=[x <= 0.7, x >= -0.7], split={"x": 0.05}, progress=False)
    assert result.verdict == "verified"
    assert result.validity == (
        f"verified inside the validated domain ({diagnosis.domain.describe()}), in the region the measurements cover; "
        "the residual bound is the largest residual measured"
    )
    # The residual is a disturbance re-drawn each step: runs drawing it anew stay inside too.
    assert _inside(result, tmp_path / "learned_generative.onnx", sensor, residual=bound) == 22 * 25


def test_leaving_the_training_domain_is_reported_and_a_stage_of_the_chain_is_refused():
    sensor = _diagnosis("knockout").system()
    loop = _loop(sensor)
    with pytest.warns(DomainWarning, match="y_knockout.*x in"):
        result = pv.verify(loop, init={"x": (1.02, 1.05)}, steps=3, safe=x <= 2.0, progress=False)
    assert result.domain_exits and result.domain_exits[0]["input"] == "x" and result.domain_exits[0]["step"] == 0
    # The sensor's validated domain (where the measurements are) is checked too.
    assert result.validity.startswith("the reach set leaves the validated domain at step 0: x in [1.02, 1.05]")
    with pytest.raises(InputError, match=r"chain of stages.*stages\(output='y'\)"):
        pv.Stage(sensor, inputs=[x], output="y")
