"""Mountain Car verification (Table 1 rows): the loop matches the networks' own chain, a verified slice
contains 1,000 sampled runs, a slice left of the verified range is falsified by a replayable run."""

import itertools
import json
import math
import subprocess
import sys

import numpy as np
import pytest

import percver as pv
from percver.cases import mountain_car as mc
from percver.cases.mountain_car import verification
from percver.errors import InputError, MissingFileError

from closed_loops import DATA


@pytest.fixture(scope="module")
def paper():
    return mc.load("paper", shared=DATA)


def test_loop_is_the_networks_chain(paper):
    """One step of the composite loop equals generator -> contrast -> blur -> estimator -> controller -> plant."""
    loop = verification.closed_loop("composite", paper)
    assert loop.states == ["p", "v", "dc", "db"]
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(-0.6, -0.4, 50), rng.uniform(-0.07, 0.07, 50), rng.uniform(0.5, 2, 50), rng.uniform(0, 0.15, 50)])
    u = paper.control(paper.estimate(paper.images(x[:, 0], delta_c=x[:, 2], delta_b=x[:, 3])), x[:, 1])
    p_next, v_next = mc.step(x[:, 0], x[:, 1], u)
    np.testing.assert_allclose(loop.step_float(x), np.column_stack([p_next, v_next, x[:, 2], x[:, 3]]), rtol=0, atol=1e-12)


def test_controller_of_another_set_drives_our_perception(paper, tmp_path):
    """``controller="paper"``: our images and estimator, the authors' controller, and their layout."""
    ours = mc.load("ours")
    loop = verification.closed_loop("contrast", "ours", controller="paper", shared=DATA)
    rng = np.random.default_rng(1)
    x = np.column_stack([rng.uniform(-0.6, -0.4, 50), rng.uniform(-0.07, 0.07, 50), rng.uniform(0.3, 2, 50)])
    p_hat = ours.estimate(ours.images(x[:, 0], delta_c=x[:, 2]))
    for controller, close in ((paper, True), (ours, False)):
        p_next, v_next = mc.step(x[:, 0], x[:, 1], controller.control(p_hat, x[:, 1]))
        expected = np.column_stack([p_next, v_next, x[:, 2]])
        assert np.allclose(loop.step_float(x), expected, rtol=0, atol=1e-12) == close
    assert [verification.layout_of(*pair) for pair in (("paper",), ("ours",), ("ours", "paper"), ("paper", "ours"))] == [
        "paper",
        "ours",
        "ours+paper",
        "ours",
    ]
    with pytest.raises(MissingFileError, match="lacks"):  # an empty folder names the file it lacks
        verification.closed_loop("contrast", "ours", controller=str(tmp_path))


def test_slice_verified_and_contains_sampled_runs(paper):
    result = mc.verify("contrast", p0=(-0.5, -0.4995), networks=paper, delta_c=(1.6, 2.0), split={}, progress=False)
    assert result.verdict == "verified" and result.coverage == 1.0
    assert result.states == ["p", "v", "dc", "r"] and result.init["v"] == (0.0, 0.0)
    loop = verification.closed_loop("contrast", paper)
    assert verification.outside_boxes(result, loop, samples=1000, seed=3) == []
    # The sampled runs satisfy the property, and the boxes are not trivially wide: the goal step's p box is narrow.
    x0 = pv.Box.coerce(result.init, result.states).sample(300, seed=4)
    traj, first = verification.runs(loop, x0)
    assert (first > 0).all() and (traj[np.arange(300), first, 3] > -10).all()
    boxes = np.asarray(result.cells[0].boxes)
    assert first.max() <= len(boxes) - 1 <= first.max() + 2 and boxes[first.min(), 0, 1] - boxes[first.min(), 0, 0] < 0.01
    row = verification.table_row(result)
    assert row["intervals"] == 1 and row["verified"] == 1 and row["avg_seconds"] > 0


def test_slice_where_some_runs_hit_the_left_wall(paper):
    """About a quarter of the runs from this slice hit p = -1.2 near step 50 (the step stage's
    undecided ``where`` forks): verified, and every sampled run stays inside its per-step boxes."""
    p0, dc = (-0.412, -0.4115), (1.0, 1.2)
    loop = verification.closed_loop("contrast", paper)
    x0 = np.column_stack([np.linspace(*p0, 200), np.zeros(200), np.full(200, 1.1)])
    traj, _ = verification.runs(loop, x0)
    hit = (traj[:, :, 0] <= -1.2).any(axis=1)
    assert 0 < hit.mean() < 1, "the slice must straddle the wall for this test to mean anything"
    result = mc.verify("contrast", p0=p0, networks=paper, delta_c=dc, split={}, progress=False)
    assert result.verdict == "verified" and result.cells[0].branches > 0
    assert verification.outside_boxes(result, loop, samples=1000, seed=5) == []


def test_left_of_the_verified_range_is_falsified_and_replays(paper):
    # From p0 < -0.6 the authors' controller does not reach the goal within 150 steps.
    result = mc.verify("contrast", p0=(-0.61, -0.605), networks=paper, delta_c=(1.0, 1.2), split={}, progress=False)
    assert result.verdict == "falsified"
    cex = result.counterexample
    assert cex is not None and -0.61 <= cex.initial["p"] <= -0.605 and 1.0 <= cex.initial["dc"] <= 1.2
    loop = verification.closed_loop("contrast", paper)
    traj, first = verification.runs(loop, [[cex.initial[n] for n in ("p", "v", "dc", "r")]])
    np.testing.assert_allclose(traj[0, : len(cex.trajectory)], cex.trajectory, rtol=0, atol=1e-12)
    reached = first[0] >= 0 and traj[0, first[0], 3] > -10
    assert not reached, "the counterexample's run reaches the goal with reward > 90"


def test_row_defaults_and_bad_input():
    assert verification.initial_set("composite") == {"p": (-0.55, -0.4), "v": (0.0, 0.0), "dc": (0.5, 2.0), "db": (0.0, 0.15)}
    assert verification.initial_set("blur", (-0.5, -0.49), delta_b=(0, 0.1))["db"] == (0.0, 0.1)
    with pytest.raises(InputError, match="delta_b"):
        verification.initial_set("contrast", delta_b=(0, 0.1))
    with pytest.raises(InputError, match="unknown Mountain Car noise"):
        verification.closed_loop("fog")
    with pytest.raises(InputError, match="lo <= hi"):
        verification.initial_set("contrast", (-0.4, -0.5))
    with pytest.raises(InputError, match="fixed by the Mountain Car property"):
        mc.verify("contrast", steps=10)


def test_rows_without_bands_run_the_adaptive_default_and_a_layout_is_data(paper):
    """Blur has no bands in the library: its slice goes whole to the adaptive splitter (no per-cell
    timeout, no bands recorded). The same slice with the old bands given as ``layout=`` runs them,
    refined with the case's timeout; ``split=`` alone makes one band of the engine's in-cell splits."""
    assert verification._layout("paper", None, "blur") is None and verification._layout("paper", None, "composite")
    assert verification._layout("ours", "paper", "blur") == verification.LAYOUT["ours+paper"]["blur"]
    row = {"p0": (-0.5, -0.4995), "networks": paper, "delta_b": (0.0, 0.05), "progress": False}
    adaptive = mc.verify("blur", **row)
    assert adaptive.verdict == "verified" and adaptive.settings["case"]["bands"] == []
    assert adaptive.settings["timeout_per_cell"] is None
    old = [verification.Band({"p": (-math.inf, verification.WALL)}, {"p": 0.00025, "db": 0.05}, 16, 4)]
    given = mc.verify("blur", layout=old, **row)
    assert given.verdict == "verified" and len(given.cells) == 2 and given.settings["timeout_per_cell"] == 60.0
    assert [(b["split"], b["max_splits"], b["order"]) for b in given.settings["case"]["bands"]] == [({"p": 0.00025, "db": 0.05}, 16, 4)]
    grid = mc.verify("blur", split={"db": 0.025}, max_splits=2, **row)
    assert grid.verdict == "verified" and len(grid.cells) == 2
    assert [(b["split"], b["max_splits"]) for b in grid.settings["case"]["bands"]] == [({"db": 0.025}, 2)]
    for bad, match in (
        ({"p": 0.001}, "non-empty list"),
        ([], "non-empty list"),
        ([{"p": 0.001}], r"layout\[0\] is"),
        ([verification.Band({"dc": (0, 1)}, {"p": 0.001}, 16)], r"layout\[0\]\.region names \['dc'\]: the blur row's states"),
        ([old[0], verification.Band({}, {"x": 0.1}, 16)], r"layout\[1\]\.cells names \['x'\]"),
    ):
        with pytest.raises(InputError, match=match):
            mc.verify("blur", layout=bad, **row)
    with pytest.raises(InputError, match="layout= or splitter="):
        mc.verify("blur", layout=old, splitter=pv.Adaptive(), **row)


def test_split_options_replace_only_what_they_name():
    init = verification.initial_set("contrast")
    layout = verification.LAYOUT["paper"]["contrast"]
    default = verification._grid(init, layout, {})
    assert [box["p"][1] for box, _ in default] == [verification.WALL, -0.4]
    options = {"max_splits": 3, "refine": False}
    bands = verification._grid(init, layout, options)
    assert [(box, band.cells, band.order) for box, band in bands] == [(box, band.cells, band.order) for box, band in default]
    assert [band.max_splits for _, band in bands] == [3, 3] and options == {"refine": False}
    (one,) = verification._grid(init, layout, {"split": {"p": 0.01}})
    assert one[0] == init and (one[1].cells, one[1].max_splits, one[1].order) == ({"p": 0.01}, layout[0].max_splits, layout[0].order)
    (none,) = verification._grid(init, layout, {"split": {}, "max_splits": 0, "order": 4})
    assert (none[1].cells, none[1].max_splits, none[1].order) == ({}, 0, 4)
    composite = verification.LAYOUT["paper"]["composite"]
    assert {band.order for _, band in verification._grid(verification.initial_set("composite"), composite, {"order": 7})} == {7}


def test_bands_partition_the_initial_set():
    layout = verification.LAYOUT["paper"]["composite"]
    bands = verification._bands(verification.initial_set("composite"), layout)

    # Each band's region is the box it covers; together they tile the row's p0 x dc x db: their
    # volumes add up to the row's and no two overlap.
    def volume(box):
        return math.prod(box[k][1] - box[k][0] for k in ("p", "dc", "db"))

    assert sum(volume(box) for box, _ in bands) == pytest.approx(0.15 * 1.5 * 0.15)
    for (a, _), (b, _) in itertools.combinations(bands, 2):
        assert any(a[k][1] <= b[k][0] or b[k][1] <= a[k][0] for k in ("p", "dc", "db")), (a, b)
    for low in (True, False):
        edges = sorted({box["p"] for box, _ in bands if (box["dc"][1] <= verification.LOW_CONTRAST) == low})
        assert edges[0][0] == -0.55 and edges[-1][1] == -0.4
    ours = verification._bands(verification.initial_set("contrast"), verification.LAYOUT["ours+paper"]["contrast"])
    assert sum(volume({**box, "db": (0, 1)}) for box, _ in ours) == pytest.approx(0.19 * 1.7)
    for (a, _), (b, _) in itertools.combinations(ours, 2):
        assert any(a[k][1] <= b[k][0] or b[k][1] <= a[k][0] for k in ("p", "dc")), (a, b)
    walls = verification._bands(verification.initial_set("contrast"), verification.LAYOUT["paper"]["contrast"])
    assert [box["p"] for box, _ in walls] == [(-0.59, verification.WALL), (verification.WALL, -0.4)]
    # A slice inside one region meets only that band; a point on a boundary goes to the upper band.
    middle = next(band for band in layout if band.region == {"p": (-0.5, -0.475), "dc": verification._HIGH})
    inside = verification._bands(verification.initial_set("composite", (-0.5, -0.49), delta_c=(1.0, 1.2)), layout)
    assert [band for _, band in inside] == [middle]
    point = verification._bands(verification.initial_set("composite", (-0.5, -0.5), delta_c=(0.8, 0.8)), layout)
    assert [box["dc"] for box, _ in point] == [(0.8, 0.8)] and point[0][1] == middle


def test_published_logs_are_summarised():
    log = verification.published("blur", shared=DATA)["log"]
    lines = (DATA / "mountain_car" / "published_results" / "BLUR_RESULTS_SUMMARY.txt").read_text().splitlines()
    assert log["safe"] == sum(", SAFE," in line for line in lines)
    assert log["p0"][0] == -0.59 and 30000 < log["avg_seconds"] < 70000


def test_unknown_cells_are_grouped_by_cause():
    # The engine's reasons, as it words them (closed_loop.rs), each under its own cause.
    reasons = {
        "step 73: the enclosure of 'v' blew up ([-3, 4]); split the cell or raise the order": "'v' blew up",
        "step 92: goal 'min((p - 0.45), (r - -10.0)) > 0.0' holds on part of the set only since step 89 (after 16 splits)": "goal met by part of the set only",
        "step 150: goal 'p >= 0.45' could not be decided (reach box p [0.1, 0.5])": "goal undecided",
        "step 12: 'v <= 0.07' could not be decided (reach box v [0, 0.08])": "a safe condition undecided",
        "timeout after 60 s at step 40": "timeout",
        "stopped at step 31 by time_limit=300 s": "the call's time limit",
        "not run within time_limit=300 s": "the call's time limit",
    }
    assert {r: verification.cause(r) for r in reasons} == reasons
    from percver.verification import Cell

    box = {"p": (-0.5, -0.49), "v": (0.0, 0.0)}
    cells = [Cell(box, "unknown", reason=r) for r in reasons] + [Cell(box, "unknown", reason="step 80: the enclosure of 'v' blew up")]
    grouped = verification.reasons(pv.Result(["p", "v"], box, cells, 1.0))
    assert grouped[0] == ("'v' blew up", 73, 80, 2) and len(grouped) == 6


def test_cli_writes_row_result_and_plots(tmp_path):
    base = [
        sys.executable,
        "-m",
        "percver.cli",
        "cases",
        "mountain-car",
        "verify",
        "--networks",
        "ours",
        "--p0",
        "-0.5",
        "-0.4995",
        "--delta-c",
        "1.5",
        "1.55",
        "--out",
        str(tmp_path),
        "--no-progress",
    ]
    r = subprocess.run(base + ["--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    record = json.loads(r.stdout)
    assert record["row"]["verified"] == record["row"]["intervals"] == 1 and record["paper"]["table"]["avg_seconds"] > 0
    assert pv.Result.from_json(str(tmp_path / "result.json")).verdict == "verified"
    assert (tmp_path / "coverage.png").stat().st_size > 5000 and (tmp_path / "tube.png").stat().st_size > 5000
    # Our perception with the authors' controller: the record names it, and the tube is drawn from that loop.
    theirs = subprocess.run(base + ["--controller", "paper", "--shared", str(DATA), "--json"], capture_output=True, text=True, timeout=300)
    assert theirs.returncode == 0, theirs.stderr
    record = json.loads(theirs.stdout)
    assert record["controller"] == "paper" and record["row"]["verified"] == record["row"]["intervals"] == 1
    bad = subprocess.run(base + ["--split", "p=wide"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1 and bad.stderr.strip().count("\n") == 0 and "NAME=WIDTH" in bad.stderr
