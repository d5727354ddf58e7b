"""F1/10 measurement simulator and particle filter: the 'real' runs, their file format, and a
filter that converges on them without ever reading the true states."""

from pathlib import Path

import numpy as np
import pytest

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import particle_filter, simulate, world
from percver.errors import InputError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "f1tenth"


@pytest.fixture(scope="module")
def runs():
    names = ["TD3_L21_64x64_C1", "DDPG_L21_64x64_C1"]
    return simulate.simulate(2, names=names, seed=3, data=DATA)


def test_real_world_scans_have_the_hidden_effects():
    real = simulate.RealWorld()
    rng = np.random.default_rng(0)
    # Centre of the first hallway, 4 m from the glass door, heading straight at it.
    pose = world.from_local([[0.75, 4.0, 0.0]])
    raw = real.scan(np.repeat(pose, 200, axis=0), rng)
    assert raw.shape == (200, 1081)
    ahead = np.argmin(np.abs(world.scanner().angles_deg))
    assert np.mean(raw[:, ahead] == 10.0) > 0.95  # the glass door is seen through: the reading saturates
    view = world.controller_view(raw)
    canonical = world.controller_lidar().scan(world.square(), pose)
    lost = simulate.reflected_rays(view, canonical)
    assert lost[:, 10].mean() > 0.95  # ahead reads max range although the model sees the door at 4 m
    assert 2.0 < lost.sum(axis=1).mean() < 6.0
    echoes = ~lost & (canonical < 5.0)
    assert 0.85 < np.mean(np.abs(view - canonical)[echoes] <= 0.05) < 0.995
    covered = real.covered()
    assert all(p.fixed for p in covered.panels) and len(covered.panels) < len(real.panels)


def test_runs_round_trip_as_measurements(runs, tmp_path):
    data = simulate.to_measurements(runs)
    assert data.measurements.shape[1] == 1081 and data.states.shape[1] == 4
    assert [r["controller"] for r in data.meta["runs"]] == runs.controllers
    path = data.save(tmp_path / "runs.npz")
    back = simulate.from_measurements(type(data).load(path))
    assert back.outcomes == runs.outcomes and np.array_equal(back.scans, runs.scans)
    assert np.all(np.diff(runs.time[runs.rows(0)]) == pytest.approx(0.025))
    stripped = type(data)(
        data.states, data.measurements[:, :21], trajectory=data.trajectory, time=data.time, controls=data.controls, meta=data.meta
    )
    with pytest.raises(InputError, match="1081"):
        simulate.from_measurements(stripped)


def test_particle_filter_converges_without_the_true_states(runs):
    settings = particle_filter.FilterSettings(particles=150)
    # The filter's inputs: scans, controls, run ids and times. No states.
    est = particle_filter.estimate_poses(runs.scans, runs.controls, runs.run, runs.time, settings=settings, seed=0)
    assert est.poses.shape == (len(runs.run), 3)
    late = runs.time >= 2.0
    errors = particle_filter.PoseEstimate(est.poses[late], est.speed[late], est.spread[late]).errors(runs.states[late])
    assert errors["position_median_m"] < 0.05
    assert errors["heading_mean_deg"] < 1.0
    for r in range(len(runs.outcomes)):
        last = runs.rows(r)[-1]
        assert np.hypot(*(est.poses[last, :2] - runs.states[last, :2])) < 0.15
    with pytest.raises(InputError, match="1081"):
        particle_filter.estimate_poses(runs.scans[:, :21], runs.controls, runs.run, runs.time)


def test_calibration_report(runs):
    report = simulate.calibration(runs)
    assert report["runs"] == 4 and report["scans"] == len(runs.run)
    assert 1.0 < report["reflected_per_scan"] < 6.0
    assert 0.85 < report["within_5cm"] <= 1.0
    assert set(runs.safe_share()) == {"TD3_L21_64x64_C1", "DDPG_L21_64x64_C1"}
    assert ctl.short_name("TD3_L21_128x128_C3") == "TD3_128_3"


def test_label_ceiling_is_what_the_likelier_label_scores_on_fresh_scans(runs):
    poses = runs.states[::3, :3]
    quiet = simulate.RealWorld(
        panels=(), gloss_deg=89.0, softness_deg=0.01, sigma=0.0, sigma_per_m=0.0, mixed_pixel_jump=100.0, outlier_rate=0.0, dropout_rate=0.0
    )
    exact = simulate.label_ceiling(quiet, poses, 0.5)
    assert exact["ceiling"] == 1.0 and exact["certain"] == 1.0  # nothing random: every label is a function of the pose
    real = simulate.RealWorld()
    found = simulate.label_ceiling(real, poses, 1.1, draws=20, seed=1)
    assert 0.0 < found["ceiling"] < 1.0 and found["ray_error"] > 0.0
    # The oracle that knows p_i predicts the likelier label; on scans drawn afresh it scores the ceiling.
    canonical = world.controller_lidar().scan(world.square(), poses)
    rng = np.random.default_rng(7)
    draws = np.stack([np.abs(world.controller_view(real.scan(poses, rng)) - canonical) > 1.1 for _ in range(40)])
    likelier = draws[:20].mean(axis=0) > 0.5
    fresh = np.mean([np.all(d == likelier, axis=1).mean() for d in draws[20:]])
    assert abs(fresh - found["ceiling"]) < 0.08
    with pytest.raises(InputError, match="2 draws"):
        simulate.label_ceiling(real, poses, 1.1, draws=1)


def test_world_description_round_trip():
    real = simulate.RealWorld(softness_deg=0.4, gloss_deg=(70.0,) * 8)
    back = simulate.RealWorld.from_description(real.describe())
    assert back.describe() == real.describe() and back.panels == real.panels
    with pytest.raises(InputError, match="world description"):
        simulate.RealWorld.from_description({"colour": "red"})
