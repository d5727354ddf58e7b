"""F1/10 canonical world: tracks, hand-computed scans, the Expr LiDAR against the numpy caster
and against the paper's Appendix B.2 sector formula, coordinates and the controller view."""

import pickle
import re
from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver.cases.f1tenth import dynamics, world
from percver.errors import InputError
from percver.sensors.lidar import Lidar

DEG = np.pi / 180
ALPHAS = np.radians(np.linspace(-115, 115, 21))


def local_scan(local, lidar=None):
    lidar = lidar or world.controller_lidar()
    return lidar.scan(world.right_turn(), world.from_local(local))


def test_hand_computed_scan_before_the_turn():
    # Centre of the first hallway, 3 m before the front wall, heading along the hallway.
    scan = local_scan([[0.75, 3.0, 0.0]])[0]
    assert scan[10] == pytest.approx(3.0, abs=1e-12)  # straight ahead: the front wall
    assert scan[0] == pytest.approx(0.75 / np.cos(25 * DEG), abs=1e-12)  # -115 deg: right wall
    assert scan[20] == pytest.approx(0.75 / np.cos(25 * DEG), abs=1e-12)  # +115 deg: left wall
    # The inner corner is at atan2(-0.75, 1.5) = -26.6 deg: -23 deg still meets the front wall...
    assert scan[8] == pytest.approx(3.0 / np.cos(23 * DEG), abs=1e-12)
    # ... -34.5 deg meets the right wall before the corner.
    assert scan[7] == pytest.approx(0.75 / np.sin(34.5 * DEG), abs=1e-12)
    # Far from the turn the rays ahead read the range limit.
    assert local_scan([[0.75, 9.0, 0.0]])[0][10] == 5.0


def test_hand_computed_scan_in_the_turn():
    # In the crossing, 1 m from the front wall: the inner corner is behind-right at (-0.5, -0.75).
    scan = local_scan([[0.75, 1.0, 0.0]])[0]
    assert scan[6] == pytest.approx(1.0 / np.cos(46 * DEG), abs=1e-12)  # -46 deg: front wall
    # -103.5 and -115 deg pass behind the corner and meet the inner wall of the second hallway.
    assert scan[1] == pytest.approx(0.5 / np.cos((180 - 103.5) * DEG), abs=1e-12)
    assert scan[0] == pytest.approx(0.5 / np.cos(65 * DEG), abs=1e-12)
    # Past the corner, heading into the second hallway (y4 = -90 deg): ahead is open.
    past = local_scan([[2.5, 0.75, -np.pi / 2]])[0]
    assert past[10] == 5.0
    assert past[0] == pytest.approx(0.75 / np.cos(25 * DEG), abs=1e-12)  # right: its inner wall


def test_right_turn_matches_the_square_loop_near_the_first_turn():
    rng = np.random.default_rng(3)
    local = np.column_stack([rng.uniform(0.2, 1.3, 300), rng.uniform(0.2, 9.0, 300), rng.uniform(-0.6, 0.6, 300)])
    poses = world.from_local(local)
    lidar = world.controller_lidar()
    assert np.max(np.abs(lidar.scan(world.square(), poses) - lidar.scan(world.right_turn(), poses))) < 1e-12


def random_turn_poses(n, seed):
    """Poses all over the right turn (first hallway, crossing, second hallway), any heading."""
    rng = np.random.default_rng(seed)
    first = np.column_stack([rng.uniform(0.02, 1.48, n), rng.uniform(0.02, 12.0, n)])
    second = np.column_stack([rng.uniform(1.52, 6.0, n), rng.uniform(0.02, 1.48, n)])
    both = np.vstack([first, second])
    return np.column_stack([both, rng.uniform(-np.pi, np.pi, len(both))])


def test_expr_scan_agrees_with_the_ray_caster():
    local = random_turn_poses(1500, seed=7)
    exprs = world.scan_exprs()
    assert len(exprs) == 21
    values = pv.evaluate(exprs, {"y1": local[:, 0], "y2": local[:, 1], "y4": local[:, 2]})
    assert np.max(np.abs(values - local_scan(local))) < 1e-9


def test_expr_scan_agrees_on_the_square_loop_and_for_the_full_scanner():
    track = world.square()
    poses = track.sample_poses(600, seed=5, margin=0.02, heading_spread_deg=180)
    x, y, theta = pv.variables("x y theta")
    lidar = world.controller_lidar()
    values = pv.evaluate(lidar.exprs(track, x, y, theta), {"x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]})
    assert np.max(np.abs(values - lidar.scan(track, poses))) < 1e-9
    full = world.scanner()
    some = Lidar(full.angles_deg[::60], full.max_range)  # 19 of the 1081 rays, 10 m
    values = pv.evaluate(some.exprs(track, "x", "y", "theta"), {"x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]})
    assert np.max(np.abs(values - some.scan(track, poses))) < 1e-9


def appendix_b2(local, limit=5.0):
    """The paper's piecewise model written independently: the wall a ray meets follows from its
    angle relative to the angles of the front-left corner and of the inner corner."""
    out = np.empty((len(local), len(ALPHAS)))
    for i, (y1, y2, y4) in enumerate(local):
        theta_l = np.arctan2(y1, y2)
        theta_r = np.arctan2(y1 - 1.5, y2 - 1.5)
        for k, alpha in enumerate(ALPHAS):
            phi = (y4 + alpha + np.pi) % (2 * np.pi) - np.pi
            right = (1.5 - y1) / np.cos(np.pi / 2 + phi)
            bottom = (1.5 - y2) / np.cos(np.pi + phi)
            front = y2 / np.cos(phi)
            left = y1 / np.cos(np.pi / 2 - phi)
            if y2 >= 1.5:
                r = right if phi <= theta_r else front if phi <= theta_l else left
            elif y1 <= 1.5:
                r = right if phi <= theta_r else bottom if phi <= -np.pi / 2 else front if phi <= theta_l else left
            else:
                r = bottom if (phi <= -np.pi / 2 or phi > theta_r) else front if phi <= theta_l else left
            out[i, k] = min(r, limit)
    return out


def test_expr_scan_is_the_papers_piecewise_model():
    local = random_turn_poses(300, seed=11)
    values = pv.evaluate(world.scan_exprs(), {"y1": local[:, 0], "y2": local[:, 1], "y4": local[:, 2]})
    assert np.max(np.abs(values - appendix_b2(local))) < 1e-9


def test_expr_scan_bounds_contain_samples():
    box = {"y1": (0.70, 0.72), "y2": (1.30, 1.32), "y4": (-0.35, -0.33)}  # in the crossing, turning
    exprs = world.scan_exprs()
    bounds = np.array(pv.bounds(exprs, box, method="interval"))
    rng = np.random.default_rng(0)
    samples = np.column_stack([rng.uniform(*box[k], 2000) for k in ("y1", "y2", "y4")])
    values = local_scan(samples)
    assert np.all(bounds[:, 0] <= values.min(axis=0) + 1e-12) and np.all(values.max(axis=0) <= bounds[:, 1] + 1e-12)
    assert np.all(np.isfinite(bounds))


def test_coordinates_and_controller_view():
    local = np.array([[0.7, 9.0, 0.1], [2.5, 0.75, -1.5]])
    assert np.allclose(world.to_local(world.from_local(local)), local)
    # The paper's features of the verification start y1 = 0.7, y2 = 9, y4 = 0.
    assert np.allclose(world.pose_features([[0.7, 9.0, 0.0]]), [[0.07, 0.1, 1 / 3]])
    assert np.allclose(world.normalise([0.0, 2.5, 5.0, 9.0]), [-0.5, 0.0, 0.5, 0.5])
    assert np.allclose(world.denormalise(world.normalise([0.3, 4.9])), [0.3, 4.9])
    raw = np.full((1, 1081), 7.0)
    raw[0, world.RAYS21] = np.linspace(1.0, 3.0, 21)
    raw[0, world.RAYS21[3]] = 0.0  # no echo
    view = world.controller_view(raw)[0]
    assert view[3] == 5.0 and view[0] == 1.0 and view[20] == 3.0
    assert np.allclose(world.scanner().angles_deg[world.RAYS21], world.controller_lidar().angles_deg)
    with pytest.raises(InputError, match="1081"):
        world.controller_view(np.zeros((2, 21)))
    with pytest.raises(InputError):
        world.right_turn(width=3.0, length=2.0)


def test_conventions_match_the_original_verisig_model():
    """Ray angles, dynamics, input normalisation and steering gain against the Verisig plant and glue
    files of the original study (Python-2 pickles of Flow*-syntax strings)."""
    folder = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "f1tenth" / "verisig"
    with open(folder / "dynamics_right_turn_21.pickle", "rb") as f:
        plant = pickle.load(f, encoding="latin1")
    with open(folder / "glue_21.pickle", "rb") as f:
        glue = pickle.load(f, encoding="latin1")
    resets = [
        r.strip()
        for mode in plant.values()
        for transition in mode["transitions"].values()
        for key, values in transition.items()
        if key.startswith("reset")
        for r in values
    ]
    offsets = {float(m.group(1)) for r in resets if (m := re.fullmatch(r"angle' := y4 \+ (-?[0-9.]+)", r))}
    assert np.allclose(sorted(np.degrees(list(offsets | {0.0}))), world.controller_lidar().angles_deg, atol=1e-6)

    ode = {name: pv.parse(text.split("=", 1)[1]) for name, text in plant[1]["dynamics"].items() if name in ("y1", "y2", "y3", "y4")}
    ours = dynamics.equations("local", delta="u")
    rng = np.random.default_rng(0)
    point = {
        "y1": rng.uniform(0, 2, 20),
        "y2": rng.uniform(0, 9, 20),
        "y3": rng.uniform(0, 2.4, 20),
        "y4": rng.uniform(-1, 1, 20),
        "u": rng.uniform(-0.26, 0.26, 20),
    }
    for name in ode:
        assert np.allclose(pv.evaluate(ode[name], point), pv.evaluate(ours[name], point), rtol=1e-10, atol=1e-12), name

    normalise = [r for r in glue["plant2dnn"][578]["reset1"] if r.startswith("_f1'")][0]
    ranges = rng.uniform(0, 5, 20)
    assert np.allclose(pv.evaluate(pv.parse(normalise.split(":=")[1]), {"_f1": ranges}), world.normalise(ranges))
    steering = glue["dnn2plant"][1]["reset1"][1]
    assert float(steering.split(":=")[1].split("*")[0]) == pytest.approx(dynamics.MAX_STEERING, abs=1e-12)
