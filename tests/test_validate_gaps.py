"""Diagnosis gaps of issue 25: missing data whose rate depends on the measurement, and the first
step of each run after an actuator delay, are reported as unexplained with their region."""

import numpy as np

import hidden_world
import percver as pv
from percver.validate import DynamicsModel, FunctionPlant
from percver.validate.regions import missing_pattern

POSES = hidden_world.poses(800, seed=1)


def _scans(**hidden):
    return pv.Measurements(POSES, hidden_world.scan(POSES, seed=2, **hidden), state_names=["x", "y", "theta"])


def test_dropout_rising_with_range_is_unexplained_not_a_uniform_dropout():
    diagnosis = pv.diagnose(pv.sensors.lidar.canonical(), _scans(dropout_far=(2.0, 5.0, 0.5)))
    assert "dropout" not in diagnosis.effects
    missing = [u for u in diagnosis.unexplained if u["kind"] == "missing"]
    assert len(missing) == 1 and "predicted range >=" in missing[0]["where"]
    assert missing[0]["rate"] > 5 * missing[0]["rate_elsewhere"] and missing[0]["share"] > 0.8
    assert "lost echoes" in diagnosis.table()


def test_uniform_dropout_has_no_pattern_and_a_ray_pattern_is_found():
    model = pv.sensors.lidar.canonical()
    predicted = model.predict(POSES)
    uniform = _scans(dropout=0.05).measurements
    assert missing_pattern(model, predicted, uniform) is None
    one_ray = uniform.copy()
    rng = np.random.default_rng(3)
    one_ray[:, 4] = np.where(rng.random(len(POSES)) < 0.4, model.range_limit(), one_ray[:, 4])
    found = missing_pattern(model, predicted, one_ray)
    assert found is not None and found["where"].startswith("lost echoes: ray ray4")


def test_first_step_of_each_run_is_named_after_a_delay():
    """The command before each run is not in the data: after the delay is found, the first step is left."""
    rng = np.random.default_rng(0)
    rows, controls, trajectory, time = [], [], [], []
    for run in range(30):
        state = np.array([[rng.uniform(-1, 0.2), rng.uniform(-0.03, 0.03)]])
        before = rng.uniform(-1, 1)
        for k in range(40):
            u = rng.uniform(-1, 1)
            rows.append(state[0].copy()), controls.append([u]), trajectory.append(run), time.append(float(k))
            state, before = hidden_world.mountain_car_step(state, np.array([[before]])), u
    data = pv.Measurements(
        np.array(rows),
        controls=np.array(controls),
        trajectory=np.array(trajectory),
        time=np.array(time),
        state_names=["p", "v"],
        control_names=["u"],
    )
    model = DynamicsModel(FunctionPlant(hidden_world.mountain_car_step, ["p", "v"], ["u"]))
    diagnosis = pv.diagnose(model, data, effects=["actuator_delay", "actuator_gain"])
    assert diagnosis.effects == ["actuator_delay"]
    start = [u for u in diagnosis.unexplained if u["kind"] == "region"]
    assert start and start[0]["where"].startswith("the first step of each run") and start[0]["share"] > 0.9
    # Without the hidden start command, no run-start region is reported.
    states, controls, trajectory, time = hidden_world.runs(30, 40, seed=5, delay=1)
    clean = pv.Measurements(states, controls=controls, trajectory=trajectory, time=time, state_names=["p", "v"], control_names=["u"])
    assert not any("first step" in u["where"] for u in pv.diagnose(model, clean, effects=["actuator_delay"]).unexplained)


def test_report_marks_every_ray_that_reads_long_and_states_its_unit(tmp_path):
    model = pv.sensors.lidar.canonical()
    rng = np.random.default_rng(6)
    scans = model.predict(POSES)
    scans[:, 8:13] *= 1.03  # rays 8-12 read 3% long: an error that varies with the range
    scans += rng.normal(0, 0.01, scans.shape)
    report = pv.compare(model, pv.Measurements(POSES, np.minimum(scans, 5.0), state_names=["x", "y", "theta"]))
    significant = {d.name for d in report.where().dimensions if d.significant}
    assert significant == {f"ray{i}" for i in range(8, 13)}
    floor = report.noise_floor
    assert np.all(floor <= np.array(list(report.per_dimension.values())) + 1e-12) and np.median(floor) < 0.02
    assert report.unit == "m"
    page = report.to_html(tmp_path, explain=False).read_text()
    assert page.count("<td>rmse</td>") == 0 and "error (rmse" in page and "unit of the errors" in page


def test_effect_causes_read_as_plain_text():
    from percver.validate.effects import library

    assert all("``" not in cls.cause() for cls in library())


def test_dropout_at_grazing_incidence_is_unexplained_by_its_angle():
    diagnosis = pv.diagnose(pv.sensors.lidar.canonical(), _scans(dropout_grazing=(60.0, 0.6)))
    assert "dropout" not in diagnosis.effects
    missing = [u for u in diagnosis.unexplained if u["kind"] == "missing"]
    assert len(missing) == 1 and "incidence >=" in missing[0]["where"], missing
    assert missing[0]["rate"] > 5 * missing[0]["rate_elsewhere"]


def test_dropout_rising_with_time_in_the_run_is_unexplained_by_time():
    """A sensor that loses more echoes the longer it runs (dust on the window): runs of 40 scans."""
    model = pv.sensors.lidar.canonical()
    time = np.tile(np.arange(40.0), len(POSES) // 40)
    scans = hidden_world.scan(POSES, seed=2)
    rng = np.random.default_rng(4)
    echo = scans < model.range_limit()
    scans = np.where(echo & (rng.random(scans.shape) < 0.4 * time[:, None] / 39), model.range_limit(), scans)
    data = pv.Measurements(POSES, scans, trajectory=np.repeat(np.arange(len(POSES) // 40), 40), time=time, state_names=["x", "y", "theta"])
    diagnosis = pv.diagnose(model, data)
    assert "dropout" not in diagnosis.effects
    missing = [u for u in diagnosis.unexplained if u["kind"] == "missing"]
    assert len(missing) == 1 and "time in run >=" in missing[0]["where"], missing


def test_first_ranking_marks_added_effects_and_stand_ins(tmp_path):
    diagnosis = pv.diagnose(pv.sensors.lidar.canonical(), _scans(scale=1.02))
    assert diagnosis.effects == ["range_scale"]
    ranking = diagnosis.rankings[0]
    verdicts = dict(zip((c.name for c in ranking), ranking.verdicts(diagnosis.effects)))
    assert verdicts["range_scale"] == "added"
    # A range bias also shortens the long rays' error alone: claimed on the baseline, but a stand-in.
    assert verdicts["range_bias"] == "stand-in" and ranking[[c.name for c in ranking].index("range_bias")].claimed
    assert set(verdicts.values()) <= {"added", "stand-in", "no"}
    page = diagnosis.to_html(tmp_path).read_text()
    assert "<td>stand-in</td>" in page and "<td>yes</td>" not in page.split("First ranking")[1].split("Baseline model")[0]
