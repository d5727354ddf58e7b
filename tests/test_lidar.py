import numpy as np
import pytest

import hidden_world
import percver as pv
from percver.errors import InputError
from percver.sensors.lidar import Lidar, canonical, square_track
from percver.validate import effects


def test_sensor_constructors():
    lidar = Lidar.f1tenth21()
    assert lidar.max_range == 5.0
    assert np.allclose(lidar.angles_deg, np.arange(-115, 115.1, 11.5))
    full = Lidar.f1tenth1081()
    assert len(full.angles_deg) == 1081 and full.max_range == 10.0
    assert full.angles_deg[0] == -135.0 and full.angles_deg[-1] == 135.0
    # The controllers' 21 rays are indices 80, 126, ..., 1000 of the full scan.
    assert np.allclose(full.angles_deg[80:1001:46], lidar.angles_deg)
    with pytest.raises(InputError):
        Lidar([], 5.0)
    with pytest.raises(InputError):
        Lidar([0.0], -1.0)


def test_hand_computed_scan_in_the_west_hallway():
    model = canonical()
    # Centre of the west hallway (walls at x = 0 and x = 1.5), driving north, 3 m before the north wall.
    scan = model.predict([[0.75, 17.0, np.pi / 2]])[0]
    angles = np.radians(np.arange(-115, 115.1, 11.5))
    assert scan[0] == pytest.approx(0.75 / np.cos(np.radians(25)), abs=1e-12)  # right wall at -115 deg
    assert scan[1] == pytest.approx(0.75 / np.cos(np.radians(13.5)), abs=1e-12)
    assert scan[20] == pytest.approx(scan[0], abs=1e-12)  # symmetric pose
    assert scan[10] == pytest.approx(3.0, abs=1e-12)  # straight ahead: the north wall
    # A ray 11.5 degrees right of ahead meets the north wall at 3 / cos(11.5 deg).
    assert scan[9] == pytest.approx(3.0 / np.cos(angles[9]), abs=1e-12)
    far = model.predict([[0.75, 5.0, np.pi / 2]])[0]
    assert far[10] == 5.0  # beyond the range limit


def test_hits_carry_wall_position_and_incidence():
    track = square_track()
    lidar = Lidar([-90.0, 0.0, 45.0], 10.0)
    hits = lidar.cast(track, np.array([0.75]), np.array([10.0]), np.array([np.pi / 2]))
    assert hits.range[0, 0] == pytest.approx(0.75)
    assert hits.cos_incidence[0, 0] == pytest.approx(1.0)
    where = hits.wall_coordinate(track)[0, 0]
    assert (track.wall_point(where)) == (pytest.approx(1.5), pytest.approx(10.0))
    assert track.wall_position(1.5, 10.0) == pytest.approx(where)
    assert hits.cos_incidence[0, 2] == pytest.approx(np.cos(np.radians(45)))
    assert hits.range[0, 1] == pytest.approx(10.0)  # north wall exactly at the limit
    assert hits.segment[0, 1] >= 0


def test_agrees_with_an_independent_caster():
    poses = hidden_world.poses(400, seed=11)
    ours = canonical().predict(poses)
    theirs = hidden_world.scan(poses, noise=0.0)
    assert np.max(np.abs(ours - theirs)) < 1e-9


def test_full_sensor_scans_fast_enough():
    poses = square_track().sample_poses(50, seed=1)
    scan = Lidar.f1tenth1081().scan(square_track(), poses)
    assert scan.shape == (50, 1081)
    assert np.all((scan > 0) & (scan <= 10.0))


def test_sample_poses_stay_inside_the_hallways():
    track = square_track()
    poses = track.sample_poses(2000, seed=3, margin=0.2, heading_spread_deg=20)
    assert np.array_equal(poses, track.sample_poses(2000, seed=3, margin=0.2, heading_spread_deg=20))
    where = track.locate(poses)
    assert np.all(where["hallway"] >= 0)
    assert np.all(np.abs(where["across"]) <= 0.75 - 0.2 + 1e-12)
    assert np.all(np.abs(np.degrees(where["heading"])) <= 20 + 1e-9)
    assert np.all((where["progress"] >= 0) & (where["progress"] <= 4 * 18.5))
    # The leftmost ray (115 deg) always meets the outer wall within (0.75 + 0.55) / cos(45 deg).
    scans = canonical(track).predict(poses)
    assert np.all(scans[:, 20] <= 1.3 / np.cos(np.radians(45)) + 1e-9)


def test_progress_runs_clockwise_around_the_loop():
    track = square_track()
    points = np.array([[0.75, 5.0, 0], [5.0, 19.25, 0], [19.25, 15.0, 0], [15.0, 0.75, 0]])
    progress = track.locate(points)["progress"]
    assert np.all(np.diff(progress) > 0)
    assert track.locate([[10.0, 10.0, 0]])["hallway"][0] == -1  # inside the inner square


def test_effects_compose_without_changing_the_original():
    model = canonical()
    biased = model.with_effect(effects.get("range_bias", bias=0.1))
    assert model.effects == ()
    turned = biased.with_effect(effects.get("angle_offset", yaw_deg=2.0))
    assert [e.name for e in turned.effects] == ["angle_offset", "range_bias"]  # mounting acts first
    pose = [[0.75, 10.0, np.pi / 2]]
    assert biased.predict(pose)[0, 0] == pytest.approx(model.predict(pose)[0, 0] + 0.1)
    limited = model.with_effect(effects.get("max_range", limit=2.0))
    assert limited.predict(pose).max() == 2.0
    with pytest.raises(InputError, match="applies to image models"):
        model.with_effect(effects.get("contrast", factor=2.0))
    with pytest.raises(InputError, match="no parameter"):
        effects.get("range_bias", offset=1.0)


def test_bad_tracks_are_refused():
    with pytest.raises(InputError):
        square_track(width=11, length=20)
    with pytest.raises(InputError):
        pv.sensors.lidar.Track(np.zeros((2, 3)))
    with pytest.raises(InputError, match="margin"):
        square_track().sample_poses(3, margin=1.0)
