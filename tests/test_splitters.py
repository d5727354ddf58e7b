"""Splitters (``pv.verify(splitter=...)``): the grid, bisection and the adaptive default."""

import json

import numpy as np
import pytest

import percver as pv
from percver.sets import Box
from percver.verification.journal import journal_cells
from percver.verification.results import Cell
from percver.verification.splitters import Retry
from test_verify import assert_contains_simulations, mountain_car


def _wall_problem():
    loop, p, v = mountain_car()
    return loop, dict(init={"p": (-0.42, -0.40), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, progress=False)


def test_the_adaptive_default_decides_what_one_cell_cannot():
    """From p0 in [-0.42, -0.40] runs hit the wall at several steps: one cell is lost, the default
    (no split given) halves where the engine lost precision and proves every part."""
    loop, kwargs = _wall_problem()
    one = pv.verify(loop, splitter=pv.Grid(), **kwargs)
    default = pv.verify(loop, **kwargs)
    assert one.verdict == "unknown" and default.verdict == "verified" and default.coverage == 1.0
    assert len(default.cells) > 1
    assert_contains_simulations(loop, default, n=2000, goal_p=0.45)
    # The cells tile the initial set exactly: widths add up, no overlaps.
    widths = sorted((c.box["p"][0], c.box["p"][1]) for c in default.cells)
    assert widths[0][0] == -0.42 and widths[-1][1] == -0.40
    assert all(a[1] == b[0] for a, b in zip(widths, widths[1:]))


def _cell(box: Box, verdict: str, **kwargs) -> Cell:
    return Cell(box.to_dict(), verdict, **kwargs)


def test_adaptive_cuts_a_cell_to_the_size_its_neighbours_needed():
    init = Box(("p", "v"), ((0.0, 1.0), (0.0, 0.0)))
    a = pv.Adaptive(rebox=False)
    parent = Box(("p", "v"), ((0.0, 0.25), (0.0, 0.0)))
    a.learn(parent, _cell(parent, "unknown"), init)
    (left, _), (right, _) = a.again(parent, _cell(parent, "unknown", split="p"), init, False)
    assert left.bounds[0] == (0.0, 0.125)
    a.learn(left, _cell(left, "verified"), init)
    assert [c.bounds[0] for c in a.prepare(Box(("p", "v"), ((0.125, 0.5), (0.0, 0.0))), init)] == [
        (0.125, 0.21875),
        (0.21875, 0.3125),
        (0.3125, 0.40625),
        (0.40625, 0.5),
    ]
    # A cell that does not touch it is left alone.
    far = Box(("p", "v"), ((0.5, 1.0), (0.0, 0.0)))
    assert a.prepare(far, init) == [far]
    # A verified cell that was cut ahead of its run (no parent failed) is no evidence of its size.
    b = pv.Adaptive(rebox=False)
    b.learn(left, _cell(left, "verified"), init)
    assert b.prepare(right, init) == [right]


def test_adaptive_stops_where_halving_does_not_push_the_loss_later():
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive(patience=2, rebox=False)
    cell, splits = init, 0
    while True:
        halves = a.again(cell, Cell(cell.to_dict(), "unknown", steps_done=5), init, False)
        if halves is None:
            break
        splits += 1
        cell = halves[0][0]
    assert splits == 2  # the first halving is free; two stalls in a row end the lineage
    # A lineage that keeps gaining steps goes on, down to min_width.
    b, cell, steps = pv.Adaptive(min_width={"x": 0.1}, rebox=False), init, 0
    while (halves := b.again(cell, Cell(cell.to_dict(), "unknown", steps_done=steps), init, False)) is not None:
        cell, steps = halves[0][0], steps + 1
    assert 0.1 <= cell.bounds[0][1] - cell.bounds[0][0] < 0.2


def test_grid_and_bisection_keep_the_old_keywords():
    loop, kwargs = _wall_problem()
    grid = pv.verify(loop, split={"p": 4}, **kwargs)
    assert len(grid.cells) == 4
    refined = pv.verify(loop, split={"p": 2}, refine=True, min_width={"p": 0.005}, **kwargs)
    assert refined.verdict == "verified" and min(c.box["p"][1] - c.box["p"][0] for c in refined.cells) >= 0.005 - 1e-12


def test_bad_splitters_are_clear_errors():
    loop, kwargs = _wall_problem()
    with pytest.raises(pv.InputError, match="not both"):
        pv.verify(loop, splitter=pv.Adaptive(), split={"p": 2}, **kwargs)
    with pytest.raises(pv.InputError, match="splitter= takes"):
        pv.verify(loop, splitter="adaptive", **kwargs)
    with pytest.raises(pv.InputError, match="max_cells"):
        pv.Adaptive(max_cells=0)
    with pytest.raises(pv.InputError, match="min_width"):
        pv.Bisection(min_width={"p": -1})
    with pytest.raises(pv.InputError, match="not states"):
        pv.verify(loop, splitter=pv.Grid({"q": 2}), **kwargs)


def test_adaptive_retries_with_rebox_where_precision_was_lost_and_stops_when_it_does_not_help():
    init = Box(("x", "y"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(patience=2)
    lost = "step 31: division is undefined on [-1, 1]: the divisor's range contains zero (after 16 splits)"
    retry = a.again(init, _cell(init, "unknown", steps_done=30, deepest_step=31, reason=lost), init, False)
    assert retry == Retry({"rebox": True})
    # The retry went deeper: its halves keep rebox.
    a.learn(init, _cell(init, "unknown", steps_done=40, deepest_step=41, reason="goal undecided", options={"rebox": True}), init)
    halves = a.again(init, _cell(init, "unknown", steps_done=40, deepest_step=41, split="x", options={"rebox": True}), init, False)
    assert [options for _, options in halves] == [{"rebox": True}] * 2
    assert [box.bounds[0] for box, _ in halves] == [(0.0, 0.5), (0.5, 1.0)]
    # The first `patience` unknown cells are retried whatever the reason; retries that go no
    # deeper stop after them, and their halves run plain.
    b = pv.Adaptive(patience=2)
    blew = "step 9: the enclosure of 'x' blew up (3e6); split the cell or raise the order"
    for k, reason in enumerate(("step 3: goal undecided", blew, "step 3: goal undecided")):
        cell = Box(("x", "y"), ((0.0, 1.0), (k / 3, (k + 1) / 3)))
        out = b.again(cell, _cell(cell, "unknown", steps_done=8, reason=reason), init, False)
        if k == 2:
            assert isinstance(out, list)  # two retries went no deeper: halved without one
            break
        assert out == Retry({"rebox": True})
        b.learn(cell, _cell(cell, "unknown", steps_done=8, reason=reason, options={"rebox": True}), init)
        halves = b.again(cell, _cell(cell, "unknown", steps_done=8, reason=reason, split="x", options={"rebox": True}), init, False)
        assert all(options == {} for _, options in halves)  # rebox did not help: the halves run plain


def test_adaptive_halves_another_state_when_the_engine_s_choice_gains_no_step():
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(rebox=False)
    cell = init
    for expected in ("p", "d", "p"):
        halves = a.again(cell, _cell(cell, "unknown", steps_done=0, deepest_step=33, split="p"), init, False)
        (left, _), _ = halves
        changed = [n for n, x, y in zip(cell.names, left.bounds, cell.bounds) if x != y]
        assert changed == [expected]
        cell = left


def _tiles(cells, init: dict) -> bool:
    """Whether the cells' boxes tile ``init``: inside it, volumes adding up, interiors disjoint."""
    import itertools

    names = [n for n, (lo, hi) in init.items() if hi > lo]
    volume = lambda b: np.prod([b[n][1] - b[n][0] for n in names])  # noqa: E731
    inside = all(init[n][0] <= c.box[n][0] <= c.box[n][1] <= init[n][1] for c in cells for n in names)
    disjoint = all(
        any(a.box[n][1] <= b.box[n][0] or b.box[n][1] <= a.box[n][0] for n in names) for a, b in itertools.combinations(cells, 2)
    )
    return inside and disjoint and np.isclose(sum(volume(c.box) for c in cells), volume(init), rtol=1e-12)


def test_a_resumed_adaptive_run_follows_the_journal_s_decisions_and_reruns_none(tmp_path):
    """Kill a run part way (its journal cut after half its lines): the resumed run runs none of
    the journal's cells again, keeps its final cells, cuts its split cells into the recorded
    pieces, and its settled cells tile the initial set with the first run's coverage."""
    loop, kwargs = _wall_problem()
    kwargs = {**kwargs, "workers": 1, "falsify": 0, "max_splits": 2}  # few in-cell splits: many cells
    whole = tmp_path / "whole.jsonl"
    first = pv.verify(loop, journal=str(whole), **kwargs)
    assert first.coverage == pytest.approx(1.0) and _tiles(first.cells, first.init)
    lines = whole.read_text().splitlines(keepends=True)
    assert len(lines) > 4
    assert [c.box["p"] for c in journal_cells(whole)] == [tuple(json.loads(x)["box"]["p"]) for x in lines[1:] if "cut" not in json.loads(x)]
    cut = tmp_path / "cut.jsonl"
    kept = [json.loads(x) for x in lines[1 : len(lines) // 2]]
    cut.write_text("".join(lines[: len(lines) // 2]))
    resumed = pv.verify(loop, journal=str(cut), **kwargs)
    assert resumed.coverage == pytest.approx(1.0) and _tiles(resumed.cells, resumed.init)
    ran = [tuple(json.loads(x)["box"]["p"]) for x in cut.read_text().splitlines()[len(lines) // 2 :] if "cut" not in json.loads(x)]
    assert ran and not set(ran) & {tuple(k["box"]["p"]) for k in kept if "cut" not in k}
    settled = {tuple(c.box["p"]) for c in resumed.cells}
    for record in kept:
        if record.get("into") is None:
            assert tuple(record["box"]["p"]) in settled
        for piece, _ in record["into"] or []:
            (lo, hi) = piece["p"]
            inside = [c for c in resumed.cells if lo <= c.box["p"][0] and c.box["p"][1] <= hi]
            assert sum(c.box["p"][1] - c.box["p"][0] for c in inside) == pytest.approx(hi - lo)


def test_with_rebox_given_the_adaptive_default_retries_nothing():
    loop, kwargs = _wall_problem()
    reboxed = pv.verify(loop, rebox=True, **kwargs)
    assert reboxed.settings["rebox"] is True and all(c.options == {} for c in reboxed.cells)


def test_spread_names_the_dimension_that_moves_the_runs():
    """x' = x + 10 d with d constant: over 5 steps the width of d moves x 50 times as far as the
    width of x does; d itself (a constant state) is not compared with itself."""
    from percver.verification.falsify import spread

    x, d = pv.variables("x d")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 10.0 * d, d: d}))
    moves = spread(loop, Box(("x", "d"), ((0.0, 1.0), (0.0, 1.0))), 5)
    assert moves["d"] == pytest.approx(1.0) and moves["x"] == pytest.approx(1 / 50)
    assert spread(loop, Box(("x", "d"), ((0.0, 0.0), (0.0, 0.0))), 5) == {}
