"""F1/10 verification (Table 1 row): the Expr LiDAR against the ray caster on the verified runs and
on sets near a wall's line, sampled trajectories inside the per-step boxes, the published results
and the CLI."""

import json
import subprocess
import sys

import numpy as np
import pytest

import percver as pv
from percver.cases.f1tenth import data, world
from percver.cases.f1tenth import verification as V
from percver.verification.solve import DEFAULTS


@pytest.fixture(scope="module")
def networks():
    return V.load_networks("paper")


@pytest.fixture(scope="module")
def loop(networks):
    return pv.ClosedLoop(V.plant(), V.perception(*networks))


def starts(lo, hi, n, seed=0):
    y1 = np.random.default_rng(seed).uniform(lo, hi, n)
    return np.column_stack([y1, np.full(n, 9.0), np.zeros(n), np.zeros(n)])


def test_expr_lidar_agrees_with_the_ray_caster_along_verified_runs(loop):
    traj = loop.simulate(starts(0.65, 0.85, 20), 46).reshape(-1, 4)
    local = traj[:, [0, 1, 3]]
    values = pv.evaluate(world.scan_exprs(), {"y1": local[:, 0], "y2": local[:, 1], "y4": local[:, 2]})
    np.testing.assert_allclose(values, world.controller_lidar().scan(world.right_turn(), world.from_local(local)), atol=1e-9)


def test_expr_lidar_is_tight_just_past_the_inner_wall_end():
    # The car 0.2-4 mm beyond the line of the first hallway's inner wall, past its end (entering the
    # turn): no ray hits that wall. Dividing by the distance to its line made every ray [-45, 101].
    box = {"y1": (1.50019, 1.50384), "y2": (0.95846, 0.95984), "y4": (-1.02896, -1.02669)}
    bounds = np.array(pv.bounds(world.scan_exprs(), box))
    grid = np.stack(np.meshgrid(*[np.linspace(*box[n], 9) for n in ("y1", "y2", "y4")]), -1).reshape(-1, 3)
    scans = world.controller_lidar().scan(world.right_turn(), world.from_local(grid))
    assert np.all(bounds[:, 0] <= scans.min(0)) and np.all(bounds[:, 1] >= scans.max(0))
    assert np.all(bounds[:, 1] - bounds[:, 0] <= np.ptp(scans, 0) + 1e-3)


def inside(traj, boxes, slack=1e-9):
    b = np.asarray(boxes)
    steps = len(b)
    return np.all((traj[:, :steps] >= b[None, :, :, 0] - slack) & (traj[:, :steps] <= b[None, :, :, 1] + slack))


def test_a_paper_cell_is_verified_at_the_defaults_and_contains_1000_trajectories(loop):
    res = V.verify((0.75, 0.75005), progress=False, workers=1, falsify=4)
    cell = res.cells[0]
    assert cell.verdict == "verified", cell.reason
    assert cell.steps_done > 40  # the turn takes about 46 periods from rest
    traj = loop.simulate(starts(0.75, 0.75005, 1000, seed=1), cell.steps_done)
    assert inside(traj, cell.boxes)
    row = V.row(res)
    assert row["intervals"] == 1 and row["coverage"] == 1.0 and row["avg_nn_seconds"] <= row["avg_seconds"]


def test_a_uniform_paper_cell_at_the_rows_order_is_verified_and_contains_1000_trajectories(loop):
    # The row's uniform cells (cell=PAPER_CELL: reboxed, order CELL_ORDER, forks), at y1 = 0.691,
    # whose undecided knock-outs fork: every sampled run stays inside the per-step boxes.
    res = V.verify((0.691, 0.69105), cell=V.PAPER_CELL, progress=False, workers=1, falsify=4)
    cell = res.cells[0]
    assert res.settings["order"] == V.CELL_ORDER < DEFAULTS.order
    assert cell.verdict == "verified" and cell.steps_done > 40, cell.reason
    assert cell.branches > 0, cell  # the cell forks on knock-outs, which this test is about
    traj = loop.simulate(starts(0.691, 0.69105, 1000, seed=3), cell.steps_done)
    assert inside(traj, cell.boxes)


def test_engine_mode_boxes_contain_1000_trajectories():
    # pv.verify as is on the loop without classifier: 12 periods, safety only.
    canonical = V.closed_loop(noise_model=False)
    res = pv.verify(
        canonical, {**V.INIT, "y1": (0.70, 0.701)}, steps=12, safe=V.property_()["safe"], progress=False, workers=1, falsify=0, max_splits=0
    )
    cell = res.cells[0]
    assert cell.verdict == "verified" and len(cell.boxes) == 13
    assert inside(canonical.simulate(starts(0.70, 0.701, 1000, seed=2), 12), cell.boxes)


def test_engine_forks_on_undecided_knockouts_and_boxes_contain_1000_trajectories(loop):
    # The whole loop with the classifier in the engine: parts restart from their boxes (rebox) and
    # fork where a knock-out is undecided; every sampled run stays inside the per-step boxes.
    res = pv.verify(
        loop,
        {**V.INIT, "y1": (0.75, 0.751)},
        steps=30,
        safe=V.property_()["safe"],
        progress=False,
        workers=1,
        falsify=0,
        rebox=True,
        max_splits=64,
        splitter=pv.Grid(),  # one cell with all its forks (the adaptive default tries few on a first cell)
    )
    cell = res.cells[0]
    assert cell.branches > 0, cell  # the test is about forks: this cell has undecided knock-outs
    runs = loop.simulate(starts(0.75, 0.751, 1000, seed=5), len(cell.boxes) - 1)
    assert inside(runs, cell.boxes)


def test_published_results_parse():
    pub = V.published()
    text = "".join((data.data_dir() / "published_results" / name).read_text() for name in V.PUBLISHED)
    assert pub["intervals"] == text.count(", SAFE,") + text.count(", UNSAFE,")
    assert 1 <= pub["avg_branches"] and pub["branches_range"][0] >= 1
    assert 0.65 <= pub["y1_range"][0] < pub["y1_range"][1] <= 0.85


def test_cli_verifies_a_canonical_slice(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "percver.cli",
            "cases",
            "f1tenth",
            "verify",
            "--y1",
            "0.75",
            "0.7501",
            "--canonical",
            "--cell",
            "5e-5",
            "--workers",
            "1",
            "--json",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    record = json.loads(out.stdout)
    assert record["row"]["intervals"] == 2 and record["row"]["coverage"] == 1.0
    assert json.loads((tmp_path / "row.json").read_text())["row"] == record["row"]
    assert (tmp_path / "result.json").is_file()


def test_bad_arguments_are_refused():
    with pytest.raises(pv.InputError, match="cell width"):
        V.verify((0.75, 0.7501), cell=-1.0)
    with pytest.raises(pv.InputError, match="lo <= hi"):
        V.verify((0.8, 0.7))
