"""Splitters (``pv.verify(splitter=...)``): the grid, bisection and the adaptive default."""

import pytest

import percver as pv
from percver.sets import Box
from percver.verification.results import Cell
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
    a = pv.Adaptive()
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
    b = pv.Adaptive()
    b.learn(left, _cell(left, "verified"), init)
    assert b.prepare(right, init) == [right]


def test_adaptive_stops_where_halving_does_not_push_the_loss_later():
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive(patience=2)
    cell, splits = init, 0
    while True:
        halves = a.again(cell, Cell(cell.to_dict(), "unknown", steps_done=5), init, False)
        if halves is None:
            break
        splits += 1
        cell = halves[0][0]
    assert splits == 2  # the first halving is free; two stalls in a row end the lineage
    # A lineage that keeps gaining steps goes on, down to min_width.
    b, cell, steps = pv.Adaptive(min_width={"x": 0.1}), init, 0
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
