"""Dynamics validation on Mountain Car runs with hidden drag, actuator delay and gain."""

import functools

import numpy as np
import pytest

import hidden_world
import percver as pv
from percver.errors import InputError, MeasurementError
from percver.validate import DynamicsModel, FunctionPlant


def _model():
    return DynamicsModel(FunctionPlant(hidden_world.mountain_car_step, ["p", "v"], ["u"]))


def _data(**hidden):
    states, controls, trajectory, time = hidden_world.runs(30, 60, seed=5, **hidden)
    return pv.Measurements(states, controls=controls, trajectory=trajectory, time=time, state_names=["p", "v"], control_names=["u"])


@functools.lru_cache(maxsize=None)
def _diagnosis(**hidden):
    return pv.diagnose(_model(), _data(**hidden))


def _params(diagnosis, name):
    return next(e for e in diagnosis.final_model.effects if e.name == name).params


SINGLE = [
    ({"drag": 0.02}, "linear_drag", {"coefficient": (0.02, 0.001)}),
    ({"delay": 2}, "actuator_delay", {"periods": (2.0, 0.1)}),
    ({"gain": 0.7}, "actuator_gain", {"gain": (0.7, 0.02)}),
]


@pytest.mark.parametrize("hidden, name, expected", SINGLE, ids=[s[1] for s in SINGLE])
def test_single_effect_is_named_and_recovered(hidden, name, expected):
    diagnosis = _diagnosis(**hidden)
    assert diagnosis.effects == [name]
    params = _params(diagnosis, name)
    for key, (value, tolerance) in expected.items():
        assert params[key] == pytest.approx(value, abs=tolerance), key
    assert diagnosis.final_error <= 0.2 * diagnosis.baseline_error


def test_drag_and_actuator_delay_together():
    diagnosis = _diagnosis(drag=0.02, delay=1)
    assert sorted(diagnosis.effects[:2]) == ["actuator_delay", "linear_drag"]
    assert _params(diagnosis, "linear_drag")["coefficient"] == pytest.approx(0.02, abs=0.002)
    assert _params(diagnosis, "actuator_delay")["periods"] == pytest.approx(1.0, abs=0.1)
    assert diagnosis.final_error <= 0.2 * diagnosis.baseline_error


def test_clean_runs_claim_nothing():
    diagnosis = _diagnosis()
    assert diagnosis.steps == []
    assert diagnosis.unexplained == []


def test_pairs_without_trajectories_still_find_drag():
    states, controls, trajectory, _ = hidden_world.runs(30, 60, seed=6, drag=0.03)
    keep = trajectory[:-1] == trajectory[1:]
    data = pv.Measurements(
        states[:-1][keep], controls=controls[:-1][keep], next_states=states[1:][keep], state_names=["p", "v"], control_names=["u"]
    )
    diagnosis = pv.diagnose(_model(), data, effects=["linear_drag", "actuator_delay", "actuator_gain"])
    assert diagnosis.effects == ["linear_drag"]  # no delay candidate: pairs carry no control history
    assert _params(diagnosis, "linear_drag")["coefficient"] == pytest.approx(0.03, abs=0.002)


def test_one_step_prediction_and_errors():
    model = _model().with_effect(pv.validate.effects.get("linear_drag", state="v", coefficient=0.5))
    assert model.predict([[0.0, 0.04]], [[0.0]])[0, 1] == pytest.approx(0.02 - 0.0025)
    with pytest.raises(MeasurementError, match="controls"):
        pv.compare(_model(), pv.Measurements(np.zeros((5, 2)), next_states=np.zeros((5, 2))))
    with pytest.raises(MeasurementError, match=r"needs controls \['u'\]"):
        data = _data()
        pv.compare(
            _model(),
            pv.Measurements(
                data.states,
                controls=data.controls,
                trajectory=data.trajectory,
                time=data.time,
                state_names=["p", "v"],
                control_names=["thrust"],
            ),
        )
    with pytest.raises(InputError, match="has no 'state_names'"):
        DynamicsModel(object())
    with pytest.raises(InputError, match="velocity states"):
        DynamicsModel(FunctionPlant(hidden_world.mountain_car_step, ["p", "v"], ["u"]), velocity="w")


def test_a_discrete_plant_of_percver_systems_is_validated_directly():
    p, v, u = pv.variables("p v u")
    v1 = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    wall = p + v1 < -1.2
    plant = pv.Discrete({p: pv.where(wall, -1.2, p + v1), v: pv.where(wall, 0.0, v1)}, inputs=[u])
    data = _data(drag=0.02)
    # One update of the expressions is the hand-written step of hidden_world.
    np.testing.assert_allclose(pv.compare(plant, data).residuals, pv.compare(_model(), data).residuals, atol=1e-12)
    diagnosis = pv.diagnose(plant, data, effects=["linear_drag", "actuator_gain", "actuator_delay"])
    assert diagnosis.effects == ["linear_drag"]
    assert _params(diagnosis, "linear_drag")["coefficient"] == pytest.approx(0.02, abs=0.001)


def test_a_continuous_plant_is_compared_over_one_control_period():
    """A double integrator x' = w, w' = u held over 0.1 s; the real actuator delivers 70% of u."""
    x, w, u = pv.variables("x w u")
    plant = pv.Continuous({x: w, w: u}, inputs=[u], period=0.1)
    rng = np.random.default_rng(8)
    states, controls, trajectory, time = [], [], [], []
    for run in range(6):
        s = rng.uniform(-1, 1, 2)
        for k in range(25):
            thrust = rng.uniform(-1, 1)
            states.append(s.copy()), controls.append([thrust]), trajectory.append(run), time.append(0.1 * k)
            s = np.array([s[0] + 0.1 * s[1] + 0.7 * thrust * 0.005, s[1] + 0.7 * thrust * 0.1])  # exact for constant u
    data = pv.Measurements(
        np.array(states),
        controls=np.array(controls),
        trajectory=np.array(trajectory),
        time=np.array(time),
        state_names=["x", "w"],
        control_names=["u"],
    )
    diagnosis = pv.diagnose(plant, data, effects=["actuator_gain", "actuator_bias"])
    assert diagnosis.effects == ["actuator_gain"]
    assert _params(diagnosis, "actuator_gain")["gain"] == pytest.approx(0.7, abs=1e-3)
    assert diagnosis.final_error < 1e-3 * diagnosis.baseline_error
