"""The diagnosed model is the model verify checks: expression forms of the effects, parameter
confidence intervals as uncertain ranges, residual bounds, the validated domain, refusals."""

import functools

import numpy as np
import pytest

import hidden_world
import percver as pv
from percver.errors import InputError
from percver.validate import DynamicsModel, FunctionPlant, effects
from percver.validate.verifiable import Domain, NoSetSemanticsError, substitute

p, v, u = pv.variables("p v u")


def _textbook():
    v1 = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    wall = p + v1 < -1.2
    return pv.Discrete({p: pv.where(wall, -1.2, p + v1), v: pv.where(wall, 0.0, v1)}, inputs=[u])


def _points(n=400, seed=0):
    rng = np.random.default_rng(seed)
    states = np.column_stack([rng.uniform(-1.2, 0.5, n), rng.uniform(-0.07, 0.07, n)])
    return states, rng.uniform(-1, 1, (n, 1))


def _update(system, states, controls, extra=None):
    values = {"p": states[:, 0], "v": states[:, 1], "u": controls[:, 0], **(extra or {})}
    return pv.evaluate(system.update, values)


def test_substitute_replaces_variables_and_keeps_parameters():
    k = pv.uncertain(1.0, 2.0)
    e = k * p + pv.sin(v) * k
    out = substitute(e, {"p": v * 2.0, "v": p + 1.0})
    assert sorted(out.variables()) == ["p", "v"]
    assert len(out.parameters()) == 1 and out.parameters()[0][0] == k.parameters()[0][0]
    a, b = np.array([0.3, -0.2]), np.array([0.1, 0.4])
    np.testing.assert_allclose(pv.evaluate(out, {"p": a, "v": b}), 1.5 * b * 2 + np.sin(a + 1) * 1.5)
    assert substitute(p, {"p": v + 1.0}).variables() == ["v"]
    same = substitute(e, {"w": p})
    assert same.structural_hash() == e.structural_hash() and same.parameters() == e.parameters()


EFFECTS = [
    effects.get("coulomb_friction", state="v", coefficient=0.0004),
    effects.get("linear_drag", state="v", coefficient=0.02),
    effects.get("quadratic_drag", state="v", coefficient=0.5),
    effects.get("actuator_gain", gain=0.9),
    effects.get("actuator_bias", bias=0.1),
    effects.get("actuator_saturation", limit=0.6),
]


@pytest.mark.parametrize("effect", EFFECTS, ids=[e.name for e in EFFECTS])
def test_each_dynamics_effect_expression_equals_its_float_form(effect):
    model = DynamicsModel(_textbook()).with_effect(effect)
    diagnosis = _fake_diagnosis(model)
    states, controls = _points()
    np.testing.assert_allclose(_update(diagnosis.model, states, controls), model.predict(states, controls), atol=1e-15)


def test_actuator_delay_keeps_earlier_controls_as_states():
    model = DynamicsModel(_textbook()).with_effect(effects.get("actuator_delay", periods=1.5))
    plant = _fake_diagnosis(model).model
    assert plant.states == ["p", "v", "u_prev1", "u_prev2"]
    states, controls = _points()
    rng = np.random.default_rng(3)
    history = rng.uniform(-1, 1, (len(states), 6, 1))
    history[:, 0] = controls
    extra = {"u_prev1": history[:, 1, 0], "u_prev2": history[:, 2, 0]}
    out = _update(plant, states, controls, extra)
    np.testing.assert_allclose(out[:, :2], model.predict(states, controls, history), atol=1e-15)
    np.testing.assert_allclose(out[:, 2], controls[:, 0])  # the lags shift
    np.testing.assert_allclose(out[:, 3], history[:, 1, 0])
    assert "u_prev1" in str(plant.validation)


def _fake_diagnosis(model):
    """A Diagnosis of ``model`` on data it explains exactly (its own predictions)."""
    states, controls, trajectory, time = hidden_world.runs(4, 30, seed=1)
    data = pv.Measurements(states, controls=controls, trajectory=trajectory, time=time, state_names=["p", "v"], control_names=["u"])
    return pv.diagnose(model, data, effects=[], max_steps=0)


def _mountain_car_data(friction, gain, runs=12, steps=60, seed=4):
    rng = np.random.default_rng(seed)
    rows, controls, trajectory, time = [], [], [], []
    for run in range(runs):
        s = np.array([rng.uniform(-1.1, 0.4), rng.uniform(-0.05, 0.05)])
        for k in range(steps):
            thrust = rng.uniform(-1, 1)
            rows.append(s + rng.normal(0, 1e-5, 2)), controls.append([thrust]), trajectory.append(run), time.append(float(k))
            w = np.sign(s[1]) * max(abs(s[1]) - friction, 0.0)
            w = float(np.clip(w + 0.0015 * gain * thrust - 0.0025 * np.cos(3 * s[0]), -0.07, 0.07))
            s = np.array([s[0] + w, w]) if s[0] + w >= -1.2 else np.array([-1.2, 0.0])
    return pv.Measurements(
        np.array(rows),
        controls=np.array(controls),
        trajectory=np.array(trajectory),
        time=np.array(time),
        state_names=["p", "v"],
        control_names=["u"],
    )


@functools.lru_cache(maxsize=None)
def _diagnosis():
    return pv.diagnose(_textbook(), _mountain_car_data(0.0004, 0.9), effects=["coulomb_friction", "actuator_gain"])


def test_diagnosed_plant_goes_into_a_closed_loop_and_matches_the_fit():
    diagnosis = _diagnosis()
    assert sorted(diagnosis.effects) == ["actuator_gain", "coulomb_friction"]
    plant = diagnosis.model
    assert isinstance(plant, pv.Discrete)
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(pv.clip(200 * v, -1, 1), inputs=[p, v], output="u")])
    assert loop.parameters() == []  # fitted values, no ranges
    states, controls = _points()
    np.testing.assert_allclose(_update(plant, states, controls), diagnosis.final_model.predict(states, controls), atol=1e-15)
    with pytest.raises(InputError, match=r"diagnosis\.model"):
        pv.ClosedLoop(diagnosis.final_model, stages=[])


def test_confidence_intervals_hold_the_truth_and_enter_as_uncertain_ranges():
    diagnosis = _diagnosis()
    intervals = diagnosis.intervals(0.95, draws=30)
    names = {diagnosis.final_model.effects[i].name: r for i, r in intervals.items()}
    lo, hi = names["coulomb_friction"]["coefficient"]
    assert lo < hi and lo - 2e-6 <= 0.0004 <= hi + 2e-6 and hi - lo < 5e-5
    lo, hi = names["actuator_gain"]["gain"]
    assert lo < hi and lo - 2e-3 <= 0.9 <= hi + 2e-3
    plant = diagnosis.system(uncertainty="ci95", draws=30)
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(pv.clip(200 * v, -1, 1), inputs=[p, v], output="u")])
    assert len(loop.parameters()) == 2
    assert plant.validation.level == 0.95
    # Sound: over a box of states and controls, the bounds of the update enclose the float
    # model at parameters drawn anywhere in the intervals.
    rng = np.random.default_rng(5)
    model = diagnosis.final_model
    for _ in range(10):
        c = np.array([rng.uniform(-1.0, 0.3), rng.uniform(-0.05, 0.05), rng.uniform(-0.8, 0.8)])
        w = np.array([0.02, 0.004, 0.2])
        box = {n: (a - b, a + b) for n, a, b in zip("pvu", c, w)}
        enclosure = pv.bounds(plant.update, box)
        points = rng.uniform(c - w, c + w, (300, 3))
        for _ in range(5):
            drawn = model.with_effects(
                [e.replace(**{n: rng.uniform(*intervals[i][n]) for n in intervals.get(i, {})}) for i, e in enumerate(model.effects)]
            )
            out = drawn.predict(points[:, :2], points[:, 2:])
            for j, (a, b) in enumerate(enclosure):
                assert np.all(out[:, j] >= a) and np.all(out[:, j] <= b)


def test_residual_enters_as_a_bounded_disturbance_and_says_which():
    diagnosis = _diagnosis()
    plant = diagnosis.system(residual="max")
    basis = plant.validation
    assert basis.residual_kind == "max" and set(basis.residual) == {"p", "v"}
    largest = np.abs(diagnosis.final.residuals).max(axis=0)
    assert basis.residual["v"] == pytest.approx(largest[1])
    lo, hi = pv.bounds(plant.update[1], {"p": (-0.5, -0.5), "v": (0.01, 0.01), "u": (0.5, 0.5)})
    assert hi - lo == pytest.approx(2 * largest[1], rel=1e-6)
    quantile = diagnosis.system(residual=0.9).validation
    assert quantile.residual["v"] < basis.residual["v"] and "statistical" in quantile.describe()
    with pytest.raises(InputError, match="quantile"):
        diagnosis.system(residual="huge")
    with pytest.raises(InputError, match="ci95"):
        diagnosis.system(uncertainty="wide")


def test_validated_domain_covers_the_data():
    diagnosis = _diagnosis()
    domain = diagnosis.domain
    states = diagnosis.final.evaluation.states
    assert domain.bounds["p"] == (states[:, 0].min(), states[:, 0].max())
    assert domain.first_exit(["p", "v"], [[(-0.5, -0.4), (0.0, 0.01)]]) is None
    step, name, _, _ = domain.first_exit(["p", "v"], [[(-0.5, -0.4), (0.0, 0.01)], [(-0.5, 5.0), (0.0, 0.01)]])
    assert (step, name) == (1, "p")


def test_verify_reports_where_reach_sets_leave_the_validated_domain():
    diagnosis = _diagnosis()
    loop = pv.ClosedLoop(diagnosis.model, stages=[pv.Stage(pv.where(v >= 0, 1.0, -1.0), inputs=[p, v], output="u")])
    inside = pv.verify(loop, init={"p": (-0.50, -0.49), "v": (0, 0)}, steps=3, safe=p >= -2.0, progress=False)
    assert inside.verdict == "verified" and inside.validity.startswith("verified inside the validated domain")
    narrow = Domain({"p": (-0.6, -0.4), "v": (-0.0005, 0.0005)})
    out = pv.verify(loop, init={"p": (-0.50, -0.49), "v": (0, 0)}, steps=3, safe=p >= -2.0, progress=False, validated=narrow)
    assert "leaves the validated domain at step 1: v" in out.validity
    plain = pv.ClosedLoop(_textbook(), stages=[pv.Stage(pv.where(v >= 0, 1.0, -1.0), inputs=[p, v], output="u")])
    assert pv.verify(plain, init={"p": (-0.50, -0.49), "v": (0, 0)}, steps=3, safe=p >= -2.0, progress=False).validity is None


def test_refusals_name_the_model_and_the_fix():
    data = _mountain_car_data(0.0004, 0.9, runs=3, steps=20)
    python_plant = pv.diagnose(FunctionPlant(hidden_world.mountain_car_step, ["p", "v"], ["u"]), data, effects=[], max_steps=0)
    with pytest.raises(NoSetSemanticsError, match="Python function.*pv.Discrete"):
        python_plant.model
    x, w = pv.variables("x w")
    continuous = DynamicsModel(pv.Continuous({x: w, w: u}, inputs=[u], period=0.1))
    with pytest.raises(NoSetSemanticsError, match="linear_drag.*pv.Discrete"):
        _fake_continuous(continuous.with_effect(effects.get("linear_drag", state="w", coefficient=0.1))).model
    gained = _fake_continuous(continuous.with_effect(effects.get("actuator_gain", gain=0.7))).model
    assert isinstance(gained, pv.Continuous)
    np.testing.assert_allclose(pv.evaluate(gained.rhs[1], {"x": [0.0], "w": [0.0], "u": [1.0]}), [0.7])


def _fake_continuous(model):
    rng = np.random.default_rng(2)
    states = rng.uniform(-1, 1, (20, 2))
    data = pv.Measurements(states, controls=rng.uniform(-1, 1, (20, 1)), next_states=states, state_names=["x", "w"], control_names=["u"])
    return pv.diagnose(model, data, effects=[], max_steps=0)


LIDAR_EFFECTS = [
    [effects.get("range_scale", scale=1.02)],
    [effects.get("range_bias", bias=0.05), effects.get("range_scale", scale=0.97)],
    [effects.get("angle_offset", yaw_deg=3.0), effects.get("position_offset", forward=0.2, left=-0.1)],
    [effects.get("max_range", limit=4.0), effects.get("range_bias", bias=-0.1)],
]


def _lidar_diagnosis(stack, poses):
    model = pv.sensors.lidar.canonical()
    for effect in stack:
        model = model.with_effect(effect)
    data = pv.Measurements(poses, model.predict(poses), state_names=["x", "y", "theta"])
    return pv.diagnose(model, data, effects=[], max_steps=0), model


@pytest.mark.parametrize("stack", LIDAR_EFFECTS, ids=["+".join(e.name for e in s) for s in LIDAR_EFFECTS])
def test_diagnosed_lidar_is_a_stage_whose_rays_equal_the_float_model(stack):
    poses = hidden_world.poses(300, seed=3)
    diagnosis, model = _lidar_diagnosis(stack, poses)
    rays = diagnosis.model
    assert rays.inputs == ("x", "y", "theta") and len(rays) == 21
    x, y, theta = pv.variables("x y theta")
    stage = pv.Stage(rays, inputs=[x, y, theta], output="scan")
    assert stage.width == 21
    values = pv.evaluate(list(rays), {"x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]})
    np.testing.assert_allclose(values, model.predict(poses), atol=1e-9)
    # Sound on sets: small pose boxes enclose the float scans of sampled poses.
    rng = np.random.default_rng(4)
    for pose in poses[:6]:
        box = {"x": (pose[0] - 0.02, pose[0] + 0.02), "y": (pose[1] - 0.02, pose[1] + 0.02), "theta": (pose[2] - 0.005, pose[2] + 0.005)}
        enclosure = np.array(pv.bounds(list(rays), box, method="interval"))
        inside = rng.uniform([b[0] for b in box.values()], [b[1] for b in box.values()], (200, 3))
        scans = model.predict(inside)
        assert np.all(scans >= enclosure[:, 0] - 1e-9) and np.all(scans <= enclosure[:, 1] + 1e-9)


def test_lidar_dropout_is_an_adversarial_knockout_and_noise_is_refused():
    poses = hidden_world.poses(200, seed=5)
    diagnosis, model = _lidar_diagnosis([effects.get("range_scale", scale=1.02), effects.get("dropout", rate=0.05)], poses)
    rays = diagnosis.model
    assert "knock-out" in str(rays.validation)
    pose = np.array([[0.7, 10.0, np.pi / 2]])  # ray 0 points east-south-east, at the inner wall 0.9 m away
    echo = model.predict(pose)[0, 0]
    lo, hi = pv.bounds(rays[0], dict(zip(["x", "y", "theta"], [(c, c) for c in pose[0]])), method="interval")
    assert echo < 1.0 and lo == pytest.approx(echo) and hi == pytest.approx(model.range_limit())
    # Simulated with the parameters at their midpoints, no ray is knocked out.
    values = pv.evaluate(list(rays), {"x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]})
    np.testing.assert_allclose(values, model.predict(poses), atol=1e-9)
    noisy, _ = _lidar_diagnosis([effects.get("gaussian_noise", sigma=0.01)], poses)
    with pytest.raises(NoSetSemanticsError, match="gaussian_noise.*residual"):
        noisy.model
