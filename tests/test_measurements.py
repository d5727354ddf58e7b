import json

import numpy as np
import pytest

import percver as pv
from percver.errors import MeasurementError


def _data(**extra):
    rng = np.random.default_rng(0)
    return pv.Measurements(
        rng.normal(size=(6, 2)),
        rng.normal(size=(6, 3)),
        state_names=["x", "v"],
        measurement_names=["a", "b", "c"],
        **extra,
    )


def test_names_and_columns():
    data = _data(meta={"site": "lab"})
    assert len(data) == 6
    assert data.state_names == ("x", "v")
    assert np.array_equal(data.column("b"), data.measurements[:, 1])
    assert np.array_equal(data.state_matrix(["v", "x"]), data.states[:, ::-1])
    with pytest.raises(MeasurementError, match="unknown column 'z'.*known: x, v, a, b, c"):
        data.column("z")
    with pytest.raises(MeasurementError, match=r"needs state \['theta'\].*state_names="):
        data.state_matrix(["x", "theta"])


def test_default_names_and_sensor_description():
    lidar = pv.sensors.lidar.Lidar.f1tenth21()
    data = pv.Measurements(np.zeros((2, 3)), np.ones((2, 21)), measurement_names=lidar)
    assert data.state_names == ("x0", "x1", "x2")
    assert data.measurement_names[20] == "ray20"


def test_nan_rows_are_named_and_can_be_dropped():
    states = np.arange(20.0).reshape(10, 2)
    readings = np.ones((10, 1))
    readings[[2, 7]] = np.nan
    states[4, 1] = np.inf
    with pytest.raises(MeasurementError, match=r"'states', 'measurements'.* rows 2, 4, 7: .*dropna=True"):
        pv.Measurements(states, readings)
    data = pv.Measurements(states, readings, dropna=True)
    assert len(data) == 7
    assert data.dropped_rows.tolist() == [2, 4, 7]


def test_shape_and_name_mismatches():
    with pytest.raises(MeasurementError, match="'measurements' has 4 rows but 'states' has 5"):
        pv.Measurements(np.zeros((5, 2)), np.zeros((4, 3)))
    with pytest.raises(MeasurementError, match="3 state names for 2 state columns"):
        pv.Measurements(np.zeros((5, 2)), state_names=["a", "b", "c"])
    with pytest.raises(MeasurementError, match="repeat"):
        pv.Measurements(np.zeros((5, 2)), state_names=["a", "a"])
    with pytest.raises(MeasurementError, match="'next_states' has 3 columns"):
        pv.Measurements(np.zeros((5, 2)), next_states=np.zeros((5, 3)))
    with pytest.raises(MeasurementError, match="shape"):
        pv.Measurements(np.zeros((5, 2, 2)))


def test_time_must_increase_within_each_trajectory():
    states = np.zeros((6, 1))
    with pytest.raises(MeasurementError, match=r"does not increase within a trajectory at row 2: .*lexsort"):
        pv.Measurements(states, trajectory=[0, 0, 0, 1, 1, 1], time=[0, 1, 1, 0, 1, 2])
    with pytest.raises(MeasurementError, match="more than one block"):
        pv.Measurements(states, trajectory=[0, 0, 1, 1, 0, 0], time=[0, 1, 0, 1, 2, 3])
    with pytest.raises(MeasurementError, match="without 'time'"):
        pv.Measurements(states, trajectory=[0, 0, 0, 1, 1, 1])


def test_transitions_from_trajectories_hold_and_break_at_gaps():
    states = np.arange(8.0)[:, None]
    controls = 10 + np.arange(8.0)[:, None]
    time = [0, 1, 2, 3, 0, 1, 3, 4]  # second run lost its sample at t = 2
    data = pv.Measurements(states, controls=controls, trajectory=[0] * 4 + [1] * 4, time=time)
    pairs = data.transitions(history=2)
    assert pairs.rows.tolist() == [0, 1, 2, 4, 6]
    assert pairs.next_states[:, 0].tolist() == [1, 2, 3, 5, 7]
    assert pairs.history[:, :, 0].tolist() == [[10, 10, 10], [11, 10, 10], [12, 11, 10], [14, 14, 14], [16, 16, 16]]
    assert pairs.has_history
    direct = pv.Measurements(states, controls=controls, next_states=states + 1).transitions(history=1)
    assert not direct.has_history and len(direct.rows) == 8
    with pytest.raises(MeasurementError, match="controls"):
        pv.Measurements(states).transitions()


def test_too_few_samples_for_the_parameters():
    data = _data()
    with pytest.raises(MeasurementError, match="7 parameters to fit but the data has only 6 samples"):
        data.require(7, "a model")
    model = pv.sensors.lidar.canonical()
    poses = model.track.sample_poses(1, seed=0)
    one = pv.Measurements(poses, model.predict(poses), state_names=["x", "y", "theta"])
    with pytest.raises(MeasurementError, match="2 parameters but only 1 samples"):
        pv.validate.fit_effect(model, pv.validate.effects.get("position_offset"), model.evaluate(one))


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_files_round_trip(tmp_path, suffix):
    data = pv.Measurements(
        np.arange(8.0).reshape(4, 2),
        np.ones((4, 3)),
        controls=np.zeros((4, 1)),
        trajectory=[0, 0, 1, 1],
        time=[0.0, 0.1, 0.0, 0.1],
        state_names=["p", "v"],
        control_names=["u"],
        meta={"note": "bench run"},
    )
    path = data.save(tmp_path / f"runs{suffix}")
    back = pv.Measurements.load(path)
    for field in ("states", "measurements", "controls", "trajectory", "time"):
        assert np.array_equal(getattr(back, field), getattr(data, field)), field
    assert back.state_names == ("p", "v") and back.control_names == ("u",)
    assert back.measurement_names == ("y0", "y1", "y2")
    assert back.meta == {"note": "bench run"}
    assert back.source == str(path)


def test_bad_files_are_refused_with_the_file_name(tmp_path):
    with pytest.raises(MeasurementError, match="does not exist"):
        pv.Measurements.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "nostates.npz", measurements=np.zeros((3, 2)))
    with pytest.raises(MeasurementError, match=r"nostates.npz' has no 'states' array \(keys: \['measurements'\]\)"):
        pv.Measurements.load(tmp_path / "nostates.npz")
    np.savez(tmp_path / "extra.npz", states=np.zeros((3, 2)), image=np.zeros(3))
    with pytest.raises(MeasurementError, match=r"unknown arrays \['image'\]"):
        pv.Measurements.load(tmp_path / "extra.npz")
    np.savez(tmp_path / "names.npz", states=np.zeros((3, 2)), names=np.array("{not json"))
    with pytest.raises(MeasurementError, match="'names' in .* is not JSON"):
        pv.Measurements.load(tmp_path / "names.npz")
    bad = np.zeros((3, 2))
    bad[1, 0] = np.nan
    np.savez(tmp_path / "nan.npz", states=bad, names=np.array(json.dumps({"states": ["a", "b"]})))
    with pytest.raises(MeasurementError, match=r"nan.npz at row 1"):
        pv.Measurements.load(tmp_path / "nan.npz")
    assert len(pv.Measurements.load(tmp_path / "nan.npz", dropna=True)) == 2
    with pytest.raises(MeasurementError, match=r"\.npz or \.parquet"):
        pv.Measurements.load(tmp_path / "nan.npz", dropna=True).save(tmp_path / "runs.csv")
