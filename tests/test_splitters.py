"""Splitters (``pv.verify(splitter=...)``): the grid, bisection and the adaptive default."""

import json
import re
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

import percver as pv
from percver.sets import Box
from percver.verification.journal import journal_cells
from percver.verification.results import Cell
from percver.verification.splitters import REDONE, Retry, _key, _touches, grid
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
    assert one.verdict == "unknown" and default.verdict == "verified" and default.coverage == pytest.approx(1.0)
    assert len(default.cells) > 1
    assert_contains_simulations(loop, default, n=2000, goal_p=0.45)
    # The cells tile the initial set exactly: widths add up, no overlaps.
    widths = sorted((c.box["p"][0], c.box["p"][1]) for c in default.cells)
    assert widths[0][0] == -0.42 and widths[-1][1] == -0.40
    assert all(a[1] == b[0] for a, b in zip(widths, widths[1:]))


def _cell(box: Box, verdict: str, **kwargs) -> Cell:
    return Cell(box.to_dict(), verdict, **kwargs)


def _gained(a, box: Box, gains: dict) -> None:
    """Primes ``a`` with halvings of cells of ``box`` that gained ``gains`` steps per state, in order."""
    for name, steps in gains.items():
        for gain in steps:
            a.near_gains.add(box, [box.names.index(name), gain])
            a.gains.setdefault(name, []).append(gain)


def test_adaptive_cuts_a_cell_to_the_size_its_neighbours_needed():
    init = Box(("p", "v"), ((0.0, 1.0), (0.0, 0.0)))
    a = pv.Adaptive(grade=4, rebox=False)
    parent = Box(("p", "v"), ((0.0, 0.25), (0.0, 0.0)))
    a.learn(parent, _cell(parent, "unknown"), init)
    (left, _), (right, _) = a.again(parent, _cell(parent, "unknown", split="p"), init, False)
    assert left.bounds[0] == (0.0, 0.125)
    a.learn(left, _cell(left, "verified"), init)
    assert [c.bounds[0] for c, _ in a.prepare(Box(("p", "v"), ((0.125, 0.5), (0.0, 0.0))), init)] == [
        (0.125, 0.21875),
        (0.21875, 0.3125),
        (0.3125, 0.40625),
        (0.40625, 0.5),
    ]
    # A verified cell that was cut ahead of its run (no parent failed) is no evidence of its size.
    b = pv.Adaptive(grade=4, rebox=False)
    b.learn(left, _cell(left, "verified"), init)
    assert b.prepare(right, init) == [right]


def test_a_cut_never_makes_more_than_max_cells_cells():
    """A size needed at a fork can be tiny in every state (a condition that crosses every cell):
    cutting a cell to it must not pass ``max_cells`` (a 64 x 64 x 64 grid had hung a campaign of 8)."""
    names = ("x", "y", "z")
    init = Box(names, ((0.0, 1.0),) * 3)
    a = pv.Adaptive(rebox=False, max_cells=8)
    cells, count = a.initial(init)
    assert count == 1 and len(list(cells)) == 1
    tiny = Box(names, ((0.0, 1e-3),) * 3)
    a.needed.append((tiny, {n: 1e-3 for n in names}))
    pieces = a.prepare(init, init)
    assert 1 < len(pieces) <= 8
    # The room is used up: the pieces are drawn as they are.
    assert all(a.prepare(piece, init) == [piece] for piece, _ in pieces)


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
    # Its neighbour verified smaller only after the cell was given up (drawn later, learnt later):
    # once every cell is settled the cell is halved again, as it would have been.
    assert a.revisit(init) == []
    lo, hi = cell.bounds[0]
    a.verified.append((Box(("x",), ((hi, hi + (hi - lo) / 2),)), 3.0))
    (given_up, pieces), *others = a.revisit(init)
    assert given_up == cell and not others and [p.bounds[0] for p, _ in pieces] == [(lo, (lo + hi) / 2), ((lo + hi) / 2, hi)]
    assert a.revisit(init) == []
    # Its halves that gain nothing stop there, but beside the verified cell (no fresh patience).
    (left, _), (right, _) = pieces
    assert a.again(left, Cell(left.to_dict(), "unknown", steps_done=5), init, False) is None
    assert a.again(right, Cell(right.to_dict(), "unknown", steps_done=5), init, False) is not None
    # Next to a cell that verified smaller, a stalled lineage goes on to one halving below its size.
    wide = Box(("x",), ((0.0, 2.0),))
    c = pv.Adaptive(patience=2, rebox=False)
    c.verified.append((Box(("x",), ((1.0, 1.0 + 1 / 32),)), 6.0))
    cell = Box(("x",), ((0.0, 1.0),))
    while (halves := c.again(cell, Cell(cell.to_dict(), "unknown", steps_done=5), wide, False)) is not None:
        cell = halves[1][0]
    assert cell.bounds[0] == (1.0 - 1 / 64, 1.0)
    # A lineage that keeps gaining steps goes on, down to min_width.
    b, cell, steps = pv.Adaptive(min_width={"x": 0.1}, rebox=False), init, 0
    while (halves := b.again(cell, Cell(cell.to_dict(), "unknown", steps_done=steps), init, False)) is not None:
        cell, steps = halves[0][0], steps + 1
    assert 0.1 <= cell.bounds[0][1] - cell.bounds[0][0] < 0.2


def test_a_stalled_lineage_of_plain_cells_runs_its_last_cell_reboxed_before_giving_it_up():
    """Halving stopped gaining: before the lineage's cell is given up it runs with the call's
    in-cell splits, then reboxed (a lineage of plain cells can stall where one reboxed run
    verifies), and only then is its verdict final."""
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive(patience=2)
    cell, options, asked = init, {}, []
    while True:
        out = _cell(cell, "unknown", steps_done=5, deepest_step=5, options=options)
        a.learn(cell, out, init)
        pieces = a.again(cell, out, init, False)
        asked.append((cell, pieces))
        if pieces is None:
            break
        if isinstance(pieces, Retry):
            options = {k: v for k, v in {**options, **pieces.options}.items() if v is not None}
        else:
            cell, options = pieces[0]
    last = [p for c, p in asked if c == cell]
    assert last[-3:] == [Retry({"max_splits": None, "max_redone": None}), Retry({"rebox": True}), None]
    assert cell.bounds[0][1] - cell.bounds[0][0] > 2 * pv.Adaptive().min_width.get("x", 1 / 8192)


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
    for window in (0, -1, 2.5, "4", None):
        with pytest.raises(pv.InputError, match=r"Adaptive\(window=\.\.\.\) must be a positive integer"):
            pv.Adaptive(window=window)
    with pytest.raises(pv.InputError, match="min_width"):
        pv.Bisection(min_width={"p": -1})
    with pytest.raises(pv.InputError, match="not states"):
        pv.verify(loop, splitter=pv.Grid({"q": 2}), **kwargs)
    with pytest.raises(pv.InputError, match=r"split= takes a dict of state names .* e\.g\. \{'p': 4\}; got 1"):
        pv.verify(loop, split=1, **kwargs)
    for spec in ("4", True, [2], None):
        with pytest.raises(
            pv.InputError, match=rf"split of 'p' must be a cell count \(int\) or a cell width \(float\), got {re.escape(repr(spec))}"
        ):
            pv.verify(loop, split={"p": spec}, **kwargs)
    for option, keyword in (("rebox", "rebox"), ("symbols", "state_symbols")):
        with pytest.raises(pv.InputError, match=rf"Adaptive\({option}=True\) is pv.verify\({keyword}=True\)"):
            pv.verify(loop, splitter=pv.Adaptive(**{option: True}), **kwargs)


def test_adaptive_retries_with_rebox_where_precision_was_lost_and_stops_when_it_does_not_help():
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive(patience=2)
    lost = "step 31: division is undefined on [-1, 1]: the divisor's range contains zero (after 16 splits)"
    retry = a.again(init, _cell(init, "unknown", steps_done=30, deepest_step=31, reason=lost), init, False)
    assert retry == Retry({"rebox": True})
    # The retry went 10 steps deeper: nothing to compare with until a plain halving has run, so
    # its halves run plain.
    deeper = _cell(init, "unknown", steps_done=40, deepest_step=41, split="x", options={"rebox": True})
    a.learn(init, deeper, init)
    halves = a.again(init, deeper, init, False)
    assert not any("rebox" in options for _, options in halves) and a.rebox_score(init) == (0, 1)
    # A plain half gains 2 steps on its parent: the retry's 10 are more than twice that, so it
    # paid, and a plain cell of that size left unknown is retried with rebox.
    (left, _), (right, _) = halves
    a.learn(left, _cell(left, "unknown", steps_done=33, deepest_step=33, reason="goal undecided"), init)
    assert a.rebox_score(init) == (1, 0)
    assert a.again(left, _cell(left, "unknown", steps_done=33, deepest_step=33, split="x"), init, False) == Retry({"rebox": True})
    # Cells of a size no plain cell has run at yet run plain first (a trial); once plain cells of
    # that size were lost more often than not they run reboxed, once they verified, plain.
    (quarter, options), _ = a.again(
        right, _cell(right, "unknown", steps_done=33, deepest_step=33, split="x", options={"rebox": True}), init, False
    )
    assert "rebox" not in options
    a.learn(quarter, _cell(quarter, "unknown", steps_done=34, deepest_step=34, options=options), init)
    assert a._options(quarter, init).get("rebox")
    for verified in (True, True):
        a.learn(quarter, _cell(quarter, "verified" if verified else "unknown", steps_done=40, deepest_step=40), init)
    assert not a._options(quarter, init).get("rebox")
    # The first `patience` unknown cells are retried whatever the reason; retries that go no
    # deeper stop after them, and their halves run plain.
    b = pv.Adaptive(patience=2)
    init = Box(("x", "y"), ((0.0, 1.0), (0.0, 1.0)))
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
        assert not any("rebox" in options for _, options in halves)  # rebox did not help: the halves run plain


def test_adaptive_retries_a_wrapped_cell_with_state_symbols_and_keeps_them_once_they_pay():
    """A cell whose enclosure wrapped (the campaign's float runs, here a stand-in) runs again with
    state symbols; once more retries paid than not, new cells run with them; retries that do not
    pay stop after ``patience`` and their halves run without."""
    init = Box(("x", "y"), ((0.0, 1.0), (0.0, 1.0)))
    lost = dict(steps_done=10, deepest_step=10, split="x", reason="step 10: goal undecided", boxes=[[[0, 1], [0, 1]]] * 11)
    seen = []
    a = pv.Adaptive(patience=2)
    a.wrapping = lambda cell: seen.append(cell) or ("x", 40.0, 1.6, 10, 64)
    assert a.again(init, _cell(init, "unknown", **lost), init, False) == Retry({"state_symbols": True}) and len(seen) == 1
    assert "state_symbols" not in a._options(init, init)  # undecided while the retry is out
    a.learn(init, _cell(init, "verified", steps_done=30, deepest_step=30, options={"state_symbols": True}), init)
    assert a.symbols_paid == [True] and a._options(init, init)["state_symbols"] is True
    # Decided: a cell drawn before that, lost without symbols, is retried with them, no float runs needed.
    half = Box(("x", "y"), ((0.0, 0.5), (0.0, 1.0)))
    assert a.again(half, _cell(half, "unknown", **lost), init, False) == Retry({"state_symbols": True}) and len(seen) == 1
    # Retries that gain nothing stop after `patience` of them, and the halves run without symbols.
    b = pv.Adaptive(patience=2, rebox=False)
    b.wrapping = a.wrapping
    for k in range(3):
        cell = Box(("x", "y"), ((0.0, 1.0), (k / 3, (k + 1) / 3)))
        out = b.again(cell, _cell(cell, "unknown", **lost), init, False)
        if k == 2:
            assert isinstance(out, list) and not any("state_symbols" in o for _, o in out)
            break
        assert out == Retry({"state_symbols": True})
        retried = _cell(cell, "unknown", **{**lost, "options": {"state_symbols": True}})
        b.learn(cell, retried, init)
        halves = b.again(cell, retried, init, False)
        assert isinstance(halves, list) and not any("state_symbols" in o for _, o in halves)
    assert b.symbols_paid == [False, False]
    # Retries still out count as lost: side by side, no more than `patience` of them before one returns.
    e = pv.Adaptive(patience=2, rebox=False)
    e.wrapping = a.wrapping
    cells = [Box(("x", "y"), ((0.0, 1.0), (k / 3, (k + 1) / 3))) for k in range(3)]
    outs = [e.again(cell, _cell(cell, "unknown", **lost), init, False) for cell in cells]
    assert outs[:2] == [Retry({"state_symbols": True})] * 2 and isinstance(outs[2], list)
    # No evidence of wrapping, a timed-out cell, or symbols=False: no retry with them.
    c = pv.Adaptive(rebox=False)
    c.wrapping = lambda cell: None
    assert isinstance(c.again(init, _cell(init, "unknown", **lost), init, False), list)
    for d, timed_out in ((pv.Adaptive(rebox=False, symbols=False), False), (pv.Adaptive(rebox=False), True)):
        d.wrapping = a.wrapping
        assert isinstance(d.again(init, _cell(init, "unknown", **lost), init, timed_out), list)


def test_the_adaptive_default_finds_state_symbols_where_the_enclosure_wraps():
    """The ReLU oscillator at order 3 without in-cell splits: its one cell's enclosure grows from its
    own fed-back errors. The default retries it with state symbols and verifies it, sound against
    float runs; told not to (``symbols=False``), or with symbols everywhere already, it never
    retries with them."""
    from test_state_symbols_continuous import loop as oscillator

    loop = oscillator()
    kwargs = dict(init={"x": (0.6, 0.65), "v": (-0.3, -0.25)}, steps=40, safe=pv.Box({"x": (-2, 2)}), order=3, max_splits=0, progress=False)
    found = pv.verify(loop, **kwargs)
    assert found.verdict == "verified" and [c.options.get("state_symbols") for c in found.cells] == [True]
    runs = loop.simulate(Box.coerce(kwargs["init"], loop.states).sample(2000), 40)
    boxes = np.asarray(found.cells[0].boxes)
    assert np.all((boxes[None, :, :, 0] <= runs) & (runs <= boxes[None, :, :, 1]))
    for options in (dict(splitter=pv.Adaptive(symbols=False)), dict(state_symbols=True)):
        result = pv.verify(loop, **kwargs, **options)
        assert not any(c.options.get("state_symbols") for c in result.cells), options


def test_a_resumed_run_replays_the_retry_with_state_symbols(tmp_path):
    """The journal holds the plain run and its retry with symbols: a rerun with it runs nothing again
    and ends with the same cell, options and boxes."""
    from test_state_symbols_continuous import loop as oscillator

    loop, journal = oscillator(), tmp_path / "osc.jsonl"
    kwargs = dict(init={"x": (0.6, 0.65), "v": (-0.3, -0.25)}, steps=40, safe=pv.Box({"x": (-2, 2)}), order=3, max_splits=0, progress=False)
    first = pv.verify(loop, journal=str(journal), **kwargs)
    lines = journal.read_text()
    assert first.verdict == "verified" and len(list(journal_cells(journal))) == 2  # the plain run, then the retry
    again = pv.verify(loop, journal=str(journal), **kwargs)
    assert journal.read_text() == lines  # no cell ran again
    assert [(c.verdict, c.options) for c in again.cells] == [(c.verdict, c.options) for c in first.cells]
    np.testing.assert_array_equal(np.asarray(again.cells[0].boxes), np.asarray(first.cells[0].boxes))


def test_adaptive_halves_another_state_when_the_engine_s_choice_gains_no_step():
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(rebox=False)
    cell = init
    for expected in ("p", "d", "p"):
        outcome = _cell(cell, "unknown", steps_done=0, deepest_step=33, split="p")
        a.learn(cell, outcome, init)
        halves = a.again(cell, outcome, init, False)
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
    # A cell is its box and its engine options: the same box may run again with others (a retry).
    run = lambda k: (tuple(k["box"]["p"]), json.dumps(k["options"], sort_keys=True))  # noqa: E731
    ran = [run(json.loads(x)) for x in cut.read_text().splitlines()[len(lines) // 2 :] if "cut" not in json.loads(x)]
    assert ran and not set(ran) & {run(k) for k in kept if "cut" not in k}
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
    assert reboxed.settings["rebox"] is True and not any("rebox" in c.options for c in reboxed.cells)


def test_spread_names_the_dimension_that_moves_the_runs():
    """x' = x + 10 d with d constant: over 5 steps the width of d moves x 50 times as far as the
    width of x does; d itself (a constant state) is not compared with itself."""
    from percver.verification.falsify import spread

    x, d = pv.variables("x d")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 10.0 * d, d: d}))
    moves = spread(loop, Box(("x", "d"), ((0.0, 1.0), (0.0, 1.0))), 5)
    assert moves["d"] == pytest.approx(1.0) and moves["x"] == pytest.approx(1 / 50)
    assert spread(loop, Box(("x", "d"), ((0.0, 0.0), (0.0, 0.0))), 5) == {}


def test_adaptive_gives_cells_far_above_the_verified_size_a_small_in_cell_budget():
    """Cells run with ``explore`` in-cell splits until a verified cell near them is at most
    ``reach`` halvings smaller; then with the call's (no ``max_splits`` of their own), those that
    restart bounded by ``REDONE`` runs' steps, except at min_width. A cell at min_width lost with
    either bound runs again without it."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(rebox=False, explore=1, reach=1)
    (whole, options), *_ = a.initial(init)[0]
    assert whole == init and options == {"max_splits": 1}
    halves = a.again(init, _cell(init, "unknown", steps_done=3, deepest_step=3, options=options), init, False)
    assert [o for _, o in halves] == [{"max_splits": 1}] * 2
    # A quarter verifies: cells within one halving of it get the call's budget, bigger ones do not.
    quarter = Box(("p", "d"), ((0.0, 0.5), (0.0, 0.5)))
    a.learn(quarter, _cell(quarter, "verified"), init)
    assert a._budget(Box(("p", "d"), ((0.5, 1.0), (0.0, 1.0))), init) == {"max_redone": REDONE}
    assert a._budget(init, init) == {"max_splits": 1}
    floor = pv.Adaptive(rebox=False, min_width={"p": 0.5, "d": 0.5})
    floor.learn(quarter, _cell(quarter, "verified"), init)
    assert floor._budget(Box(("p", "d"), ((0.5, 1.0), (0.0, 0.5))), init) == {}
    # A cell whose budget was not enough and that cannot be halved runs again with the call's.
    tiny = pv.Adaptive(rebox=False, min_width={"p": 0.5, "d": 0.5})
    unbounded = Retry({"max_splits": None, "max_redone": None})
    assert tiny.again(quarter, _cell(quarter, "unknown", options={"max_splits": 0}), init, False) == unbounded
    assert tiny.again(quarter, _cell(quarter, "unknown", options={"max_redone": REDONE}), init, False) == unbounded
    assert tiny.again(quarter, _cell(quarter, "unknown", options={}), init, False) is None


def test_adaptive_halves_the_state_whose_halvings_gained_the_most_steps():
    """Each state is tried once; then the one whose halvings pushed the loss of precision later
    wins over the engine's (and the probe's) choice."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(rebox=False)

    def halve(cell, deepest):
        (left, _), _ = a.again(cell, _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest, split="p"), init, False)
        return left, next(n for n, x, y in zip(cell.names, left.bounds, cell.bounds) if x != y)

    half, state = halve(init, 33)
    assert state == "p"  # the engine's choice first
    a.learn(half, _cell(half, "unknown", steps_done=34, deepest_step=34), init)  # one step more
    quarter, state = halve(half, 34)
    assert state == "d"  # untried
    a.learn(quarter, _cell(quarter, "unknown", steps_done=64, deepest_step=64), init)  # 30 steps more
    _, state = halve(quarter, 64)
    assert state == "d" and a.gains == {"p": [1], "d": [30]}


def test_a_reboxed_retry_pays_by_steps_gained_against_halving_not_by_seconds():
    """Twice as deep is not enough where a plain halving gains as much (a reboxed step costs
    about two plain ones), however few seconds the retry took: the first runs last a fraction of
    a second and their seconds are the load's. Where halving gains little, it pays. A retry that
    verifies is judged the same way, by the steps it went deeper (a plain halving might have
    verified as well, for as little)."""
    init = Box(("x",), ((0.0, 1.0),))
    plain = _cell(init, "unknown", seconds=1.0, steps_done=33, deepest_step=33)
    for verdict, deepest in (("unknown", 65), ("verified", 65)):
        for half_gain, paid in ((31, False), (1, True)):
            a = pv.Adaptive(patience=2)
            assert a.again(init, plain, init, False) == Retry({"rebox": True})
            retry = _cell(init, verdict, seconds=0.1, steps_done=deepest, deepest_step=deepest, split="x", options={"rebox": True})
            a.learn(init, retry, init)
            assert a.rebox_score(init) == (0, 1)  # undecided until a plain halving of its size has run
            # A plain half of the cell, as the splitter makes them, and what it gained.
            (half, options), _ = a.again(init, _cell(init, "unknown", steps_done=33, deepest_step=33, split="x"), init, False)
            a.learn(
                half, _cell(half, "unknown", seconds=1.0, steps_done=33 + half_gain, deepest_step=33 + half_gain, options=options), init
            )
            assert a.rebox_score(init) == ((1, 0) if paid else (0, 1)), (verdict, half_gain)


def test_a_verified_reboxed_retry_is_judged_by_the_states_halved_near_its_size():
    """A splitter that learns which state to halve leaves others unhalved for many sizes
    (docking's four states): a retry that verified is judged against the states that were, and
    must also gain an eighth of the plain run's steps (a state whose halving gains nothing must
    not make a retry that gains as little win). One that did not verify waits for every state."""
    init = Box(("x", "y"), ((0.0, 1.0), (0.0, 1.0)))
    for verdict, retry_gain, half_gain, paid in (
        ("verified", 15, 2, True),
        ("verified", 2, 0, False),
        ("verified", 15, 8, False),
        ("unknown", 15, 2, False),
    ):
        a = pv.Adaptive(patience=2)
        assert a.again(init, _cell(init, "unknown", steps_done=20, deepest_step=20), init, False) == Retry({"rebox": True})
        a.learn(init, _cell(init, verdict, steps_done=20 + retry_gain, deepest_step=20 + retry_gain, options={"rebox": True}), init)
        assert a.rebox_score(init) == (0, 1)  # undecided: no state halved plain near its size
        (half, options), _ = a.again(init, _cell(init, "unknown", steps_done=20, deepest_step=20, split="x"), init, False)
        a.learn(half, _cell(half, "unknown", steps_done=20 + half_gain, deepest_step=20 + half_gain, options=options), init)
        assert not a.plain_gains.get("y")
        assert a.rebox_score(init) == ((1, 0) if paid else (0, 1)), (verdict, retry_gain, half_gain)


def test_a_cell_that_verified_only_reboxed_teaches_no_size():
    """Lost plain and verified reboxed, a cell says reboxed runs verify at its size, not that
    cells must be that small: docking's plain cells are lost at every size where reboxed ones
    2^8 times as large verify, and cut to such sizes its cells would be ten thousand times too
    many. A half that verified plain after its plain parent was lost does teach its size."""
    init = Box(("x",), ((0.0, 1.0),))
    for reboxed in (True, False):
        a = pv.Adaptive(patience=2)
        lost = _cell(init, "unknown", steps_done=5, deepest_step=5, split="x")
        assert a.again(init, lost, init, False) == Retry({"rebox": True})
        a.learn(init, replace(lost, options={"rebox": True}), init)
        (half, options), _ = a.again(init, replace(lost, options={"rebox": True}), init, False)
        assert "rebox" not in options
        if reboxed:
            a.learn(half, _cell(half, "unknown", steps_done=6, deepest_step=6, split="x", options=options), init)
            assert a.again(half, _cell(half, "unknown", steps_done=6, deepest_step=6, split="x", options=options), init, False) == Retry(
                {"rebox": True}
            )
            options = {"rebox": True}
        a.learn(half, _cell(half, "verified", steps_done=40, deepest_step=40, options=options), init)
        assert bool(a.needed) is not reboxed


def test_cells_run_reboxed_at_rebox_order_and_their_plain_halves_at_the_call_s():
    """A reboxed run's models restart from a box, a variable per state: with ``rebox_order`` it
    runs at that order where the call's is higher, and a lost run is not run again at the call's;
    halves that run plain take the call's."""
    assert pv.Adaptive().rebox_order is None
    init = Box(("x",), ((0.0, 1.0),))
    lost = _cell(init, "unknown", steps_done=5, deepest_step=5, split="x")
    for call_order, rebox_order, expected in ((5, 3, {"rebox": True, "order": 3}), (2, 3, {"rebox": True}), (5, 5, {"rebox": True})):
        a = pv.Adaptive(patience=2, rebox_order=rebox_order)
        a.call_order = call_order
        retry = a.again(init, lost, init, False)
        assert retry == Retry(expected)
        a.learn(init, replace(lost, options=retry.options), init)
        halves = a.again(init, replace(lost, options=retry.options), init, False)
        assert all(options == {"max_splits": 0} for _, options in halves), halves


def _low_then_call_order(a, cell: Box, init: Box, low: str, rerun: str) -> list:
    """Runs ``cell`` plain (lost), then as ``a`` says: ``low`` and ``rerun`` are the verdicts of its
    reboxed runs at LOW_ORDER and at the call's order; returns what ``a`` asked for in turn."""
    verdicts = {3: low, None: rerun}
    out = _cell(cell, "unknown", steps_done=5, deepest_step=5, split="x")
    asked = []
    while True:
        a.learn(cell, out, init)
        pieces = a.again(cell, out, init, False)
        asked.append(pieces)
        if not isinstance(pieces, Retry):
            return asked
        options = {k: v for k, v in {**out.options, **pieces.options}.items() if v is not None}
        verdict = verdicts[options.get("order")]
        out = _cell(cell, verdict, steps_done=5 + 5 * (verdict == "verified"), deepest_step=5, split="x", options=options)


def test_reboxed_runs_start_at_order_3_once_one_verified_and_a_lost_one_runs_again_at_the_call_s():
    """``rebox_order=None`` (the default): once a reboxed run at the call's order has verified,
    reboxed runs start at LOW_ORDER (3) where the call's order is higher, and one that is lost
    runs again at the call's. Where the reruns verify and order 3 never does (a camera loop:
    unknown after 4,763 cells at order 3, 44 reboxed at 5), reboxed runs go back to the call's
    order after ``patience`` reruns that did better; where order 3 verifies (docking), lost runs at
    it are no longer run again and the cell is halved."""
    init = Box(("x",), ((0.0, 1.0),))
    cells = init.split({"x": 8})

    def primed():
        a = pv.Adaptive(patience=2)
        a.call_order = 5
        # No reboxed run has verified: the call's order (where none verifies, order 3 would only add runs).
        assert _low_then_call_order(a, cells[7], init, "unknown", "verified")[0] == Retry({"rebox": True})
        return a

    needs_call_order = primed()
    first = _low_then_call_order(needs_call_order, init, init, "unknown", "verified")
    assert first == [Retry({"rebox": True, "order": 3}), Retry({"rebox": True, "order": None}), None]
    assert _key(init) in needs_call_order.verified_retries  # the retry is judged by its rerun
    second = _low_then_call_order(needs_call_order, cells[0], init, "unknown", "verified")
    assert second[:2] == [Retry({"rebox": True, "order": 3}), Retry({"rebox": True, "order": None})]
    # Two reruns did better and no run at order 3 verified: the next reboxed run is at the call's.
    assert needs_call_order._reboxed(_key(cells[1])) == {"rebox": True}

    low_pays = primed()
    for cell in cells[:2]:  # cells made to run reboxed (halves, cut pieces) that verify at order 3
        options = low_pays._reboxed(_key(cell))
        assert options == {"rebox": True, "order": 3}
        low_pays.learn(cell, _cell(cell, "verified", steps_done=10, deepest_step=10, options=options), init)
    options = low_pays._reboxed(_key(cells[2]))
    assert options == {"rebox": True, "order": 3}
    # Order 3 verified patience times more often than reruns did better: a lost run is halved.
    lost = _cell(cells[2], "unknown", steps_done=5, deepest_step=5, split="x", options=options)
    low_pays.learn(cells[2], lost, init)
    halves = low_pays.again(cells[2], lost, init, False)
    assert [box for box, _ in halves] == list(cells[2].split({"x": 2}))
    with pytest.raises(pv.InputError, match=r"Adaptive\(rebox_order=\.\.\.\) must be a positive integer or None, got 0"):
        pv.Adaptive(rebox_order=0)


def test_cells_run_side_by_side_are_not_all_retried_before_a_retry_shows_whether_it_pays():
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive()
    cells = [Box(("x",), ((k / 4, (k + 1) / 4),)) for k in range(4)]
    outs = [a.again(c, _cell(c, "unknown", seconds=1.0, steps_done=3, deepest_step=3, split="x"), init, False) for c in cells]
    assert [isinstance(o, Retry) for o in outs] == [True, True, False, False]


def test_adaptive_cuts_a_cell_to_the_nearest_size_needed_when_none_touches_it():
    init = Box(("p", "v"), ((0.0, 1.0), (0.0, 0.0)))
    parent = Box(("p", "v"), ((0.0, 0.25), (0.0, 0.0)))
    far = Box(("p", "v"), ((0.5, 1.0), (0.0, 0.0)))
    for tile, pieces in ((True, 4), (False, 1)):
        a = pv.Adaptive(grade=4, rebox=False, tile=tile)
        (left, _), _ = a.again(parent, _cell(parent, "unknown", split="p"), init, False)
        a.learn(left, _cell(left, "verified"), init)
        assert len(a.prepare(far, init)) == pieces


class _Recorded(pv.Adaptive):
    """Adaptive, noting when a cell is drawn to run and when an outcome is learnt (a class list:
    verify runs a copy of the splitter)."""

    events: list = []

    def prepare(self, cell, init):
        pieces = super().prepare(cell, init)
        if pieces == [cell]:
            _Recorded.events.append("draw")
        return pieces

    def learn(self, cell, result, init):
        _Recorded.events.append("learn")
        super().learn(cell, result, init)


@pytest.mark.parametrize("window", [1, 3])
def test_the_adaptive_default_draws_each_cell_after_the_outcomes_before_its_window(window):
    """No cell is drawn (and cut) before the outcomes of all cells drawn before it but the last
    ``window`` are learnt (a stock of cells drawn ahead would be cut before the outcomes that
    should shape them), and no outcome is learnt earlier than that while cells are left to draw."""
    loop, kwargs = _wall_problem()
    _Recorded.events.clear()
    result = pv.verify(loop, splitter=_Recorded(rebox=False, window=window), workers=1, **kwargs)
    assert result.coverage == pytest.approx(1.0)
    events = _Recorded.events
    assert events.count("draw") > 3
    draws = learns = 0
    for event in events:
        if event == "draw":
            assert learns >= draws - window + 1
            draws += 1
        else:
            learns += 1
    lags = [events[: k + 1].count("draw") - events[:k].count("learn") for k, e in enumerate(events) if e == "draw"]
    assert max(lags) == 1 if window == 1 else max(lags) > 1  # held back while cells were left


def test_only_settled_unknown_cells_are_sampled(monkeypatch):
    """Random runs go to the cells a splitter settles unknown, not to the cells it cuts (their
    pieces are probed): each settled unknown cell is sampled once, a halved one never."""
    from percver.verification import campaign

    sampled = []

    def counted(loop, prop, cells, steps, samples, seed, probe=True):
        if not probe:
            sampled.extend(tuple(cell.bounds) for cell in cells)
        return [None] * len(cells)

    monkeypatch.setattr(campaign, "falsify", counted)
    loop, kwargs = _wall_problem()
    result = pv.verify(loop, splitter=pv.Bisection(min_width={"p": 0.005}), max_splits=0, workers=1, **kwargs)
    unknown = sorted(tuple(tuple(c.box[n]) for n in ("p", "v")) for c in result.cells if c.verdict == "unknown")
    assert unknown and sorted(sampled) == unknown
    assert len(result.cells) > 1  # cells were halved, and none of them sampled


def test_the_state_to_halve_is_chosen_by_the_gains_of_halvings_near_the_cell():
    """Halvings of d gained 31 steps and p's none: a cell among them halves d; a cell far from
    them halves the engine's choice, p (there each state is tried first). Mountain Car's contrast
    row had taught dc's gains far from the goal to the cells near it, where dc does not matter."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    cell = Box(("p", "d"), ((0.0, 0.25), (0.0, 0.25)))
    for where, expected in ((init, "d"), (Box(("p", "d"), ((0.9, 1.0), (0.9, 1.0))), "p")):
        a = pv.Adaptive(rebox=False)
        _gained(a, where, {"p": [0], "d": [31]})
        (left, _), _ = a.again(cell, _cell(cell, "unknown", steps_done=40, deepest_step=40, split="p"), init, False)
        assert next(n for n, x, y in zip(cell.names, left.bounds, cell.bounds) if x != y) == expected


def test_a_halving_that_gained_no_step_switches_the_lineage_to_another_state_at_once():
    """Halving d gained 31 steps near the whole set, p none; in a lineage where halving d no
    longer gains (or gains a step of 60, less than MIN_GAIN of them), the next halving is p's,
    whatever the gains measured elsewhere say."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    for later, switched in ((60, True), (61, True), (60 + 60 // 4, False)):
        a = pv.Adaptive(rebox=False)
        _gained(a, init, {"p": [0], "d": [31]})

        def halve(cell, deepest):
            (left, _), _ = a.again(cell, _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest, split="d"), init, False)
            return left, next(n for n, x, y in zip(cell.names, left.bounds, cell.bounds) if x != y)

        half, state = halve(init, 60)
        assert state == "d"
        _, state = halve(half, later)
        assert state == ("p" if switched else "d")


def test_a_state_whose_halving_left_the_enclosure_as_wide_is_not_halved_again_in_its_lineage():
    """d is a parameter (its reach box is the cell's) and p a state that moves. Halving d gained
    no step; halving p gained none either, but narrowed p's enclosure at the step where the
    cell was lost. If d's halving left that enclosure as wide, the lineage halves p again (the turn
    to another state after a halving that gained nothing would pick d); if it narrowed it, d."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    for d_halved_width, expected in ((6.0, "p"), (5.0, "d")):
        a = pv.Adaptive(rebox=False)
        _gained(a, init, {"p": [0], "d": [31]})

        def halve(cell, p_width):
            d = cell.bounds[1]
            boxes = [[(-p_width / 2, p_width / 2), d]] * 61
            run = _cell(cell, "unknown", steps_done=60, deepest_step=60, split="d", boxes=boxes, options={"max_splits": 0})
            (left, _), _ = a.again(cell, run, init, False)
            return left, next(n for n, x, y in zip(cell.names, left.bounds, cell.bounds) if x != y)

        half, state = halve(init, 6.0)
        assert state == "d"
        half, state = halve(half, d_halved_width)
        assert state == "p"
        _, state = halve(half, 0.6 * d_halved_width)
        assert state == expected


def test_the_size_a_verified_half_needed_undoes_the_halvings_of_its_lineage_that_gained_no_step():
    """d halved twice (the second gained nothing), then p: the half verifies. Neighbours are cut
    to p's width and to d's width before the halving that gained nothing, not to the half's."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(rebox=False)
    _gained(a, init, {"p": [0], "d": [10]})
    cell = Box(("p", "d"), ((0.0, 0.5), (0.0, 1.0)))
    for state, deepest in (("d", 40), ("d", 60), ("p", 60)):
        a.learn(cell, _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest), init)
        halves = a.again(cell, _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest, split=state), init, False)
        (cell, _), _ = halves
    assert (cell.bounds[0][1] - cell.bounds[0][0], cell.bounds[1][1] - cell.bounds[1][0]) == (0.25, 0.25)
    a.learn(cell, _cell(cell, "verified", steps_done=90, deepest_step=90), init)
    assert a.needed[-1][1] == {"p": 0.25, "d": 0.5}
    neighbour = Box(("p", "d"), ((0.25, 0.5), (0.0, 1.0)))
    assert sorted(piece.bounds[1] for piece, _ in a.prepare(neighbour, init)) == [(0.0, 0.5), (0.5, 1.0)]


def test_a_cell_is_cut_to_one_shape_needed_near_it_not_to_the_narrowest_widths_of_several():
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(grade=4, rebox=False)
    a.needed += [(Box(("p", "d"), ((0.25, 0.5), (0.0, 0.5))), {"p": 0.25, "d": 0.5})]
    a.needed += [(Box(("p", "d"), ((0.0, 0.5), (0.5, 1.0))), {"p": 0.5, "d": 0.25})]
    cell = Box(("p", "d"), ((0.5, 1.0), (0.0, 1.0)))
    pieces = a.prepare(cell, init)
    assert len(pieces) == 4 and {(p.bounds[0][1] - p.bounds[0][0], p.bounds[1][1] - p.bounds[1][0]) for p, _ in pieces} == {(0.5, 0.25)}


def test_a_cut_to_a_width_that_differs_by_float_rounding_makes_no_extra_pieces():
    """Widths made by the same halvings of different cells differ in their last bits: a cell
    twice the needed width is cut in two, not four."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.3, 2.0)))
    a = pv.Adaptive(rebox=False)
    lo, mid, hi = 0.725, 0.9375, 1.04375
    assert (mid - lo) / (hi - mid) > 2  # 0.2125 / 0.10625 in floats
    a.needed.append((Box(("p", "d"), ((0.0, 0.5), (mid, hi))), {"p": 0.5, "d": hi - mid}))
    assert len(a.prepare(Box(("p", "d"), ((0.0, 0.5), (lo, mid))), init)) == 2


def _halve(a, cell, init, deepest, reason="goal undecided", options=None, split="p"):
    """The adaptive's answer to ``cell`` lost at step ``deepest`` (learnt first, as the campaign does)."""
    outcome = _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest, split=split, reason=reason, options=options or {})
    a.learn(cell, outcome, init)
    return a.again(cell, outcome, init, False)


ARRIVED = "step 96: goal 'p >= 0.45' holds on part of the set only since step 85"


def test_a_cell_lost_to_a_partly_reached_goal_that_halving_did_not_move_runs_with_the_call_s_splits():
    """Runs from parts of a cell arriving at different steps are what in-cell forks separate: a
    cell run with the small budget and lost so, after a halving that gained nothing, runs again
    with the call's splits instead of being halved. A blow-up, a halving that gained, or a loss
    far earlier than where the verified cells near it arrived is halved as before."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    small = {"max_splits": 0}

    def second(reason, later, arrived=None):
        a = pv.Adaptive(rebox=False)
        if arrived is not None:
            done = Box(("p", "d"), ((0.9375, 1.0), (0.9375, 1.0)))  # far smaller: the halves keep the small budget
            a.learn(done, _cell(done, "verified", steps_done=arrived, deepest_step=arrived), init)
        (half, options), _ = _halve(a, init, init, 95, ARRIVED, small)
        return a, half, _halve(a, half, init, later, reason, options)

    a, half, out = second(ARRIVED, 96)
    assert out == Retry({"max_splits": None, "rebox": None, "order": None})
    # The retry is lost too: halved, and the halves (small budget again) compare with the run before it.
    deeper = _cell(half, "unknown", steps_done=99, deepest_step=99, split="d", reason=ARRIVED)
    a.learn(half, deeper, init)
    halves = a.again(half, deeper, init, False)
    assert isinstance(halves, list) and all(o == small for _, o in halves)
    assert a.lineage[_key(halves[0][0])][:2] == (96, 96)
    blew = "step 96: the enclosure of 'p' blew up (3e6); split the cell or raise the order"
    assert isinstance(second(blew, 96)[2], list)
    assert isinstance(second(ARRIVED, 95 + 95 // 4)[2], list)  # the halving gained a fair share
    assert isinstance(second(ARRIVED, 96, arrived=140)[2], list)  # far from where the verified cells' runs arrived
    assert second(ARRIVED, 96, arrived=100)[2] == Retry({"max_splits": None, "rebox": None, "order": None})


def test_a_state_whose_width_does_not_change_how_the_pieces_of_a_cut_end_is_grown_back():
    """A cell cut to a needed 1/8 x 1/8: pieces side by side along d that verify at the same step
    with as many splits say d's width did not matter there, so the next cell is cut twice as wide
    in d; along p they differ, so p keeps its width. One piece that differs (or is lost) along a
    state keeps that state's width. Pieces that verified with no in-cell split at all end alike
    at any step."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))

    def cut_and_settle(step_of, branches=1):
        a = pv.Adaptive(grade=4, rebox=False)
        a.needed.append((Box(("p", "d"), ((0.0, 0.125), (0.0, 0.125))), {"p": 0.125, "d": 0.125}))
        pieces = [c for c, _ in a.prepare(Box(("p", "d"), ((0.0, 0.5), (0.0, 0.5))), init)]
        assert len(pieces) == 16
        for piece in pieces:
            (plo, _), (dlo, _) = piece.bounds
            deepest = step_of(round(plo * 8), round(dlo * 8))
            verdict = "unknown" if deepest is None else "verified"
            a.learn(piece, _cell(piece, verdict, steps_done=deepest or 50, deepest_step=deepest or 50, branches=branches), init)
        nxt = [c if isinstance(c, Box) else c[0] for c in a.prepare(Box(("p", "d"), ((0.5, 1.0), (0.0, 0.5))), init)]
        return {(round(hi - lo, 6), round(dhi - dlo, 6)) for (lo, hi), (dlo, dhi) in (c.bounds for c in nxt)}

    assert cut_and_settle(lambda i, j: 90 + i) == {(0.125, 0.25)}
    assert cut_and_settle(lambda i, j: 90 + i + (j == 3)) == {(0.125, 0.125)}
    assert cut_and_settle(lambda i, j: None if (i, j) == (3, 3) else 90 + i) == {(0.125, 0.125)}
    assert cut_and_settle(lambda i, j: 90) == {(0.25, 0.25)}
    # Pieces that verified without any in-cell split end alike whatever their step: p grows too.
    assert cut_and_settle(lambda i, j: 90 + i, branches=0) == {(0.25, 0.25)}


def test_pieces_that_split_and_computed_steps_again_make_the_next_cells_smaller_forks_do_not():
    """Cut pieces of 1/8 x 1/8 all verify at the same step with one in-cell split each. Where the
    split restarted from step 0 (``steps_redone`` 60 of 95 steps: the run cost about three), the
    next cell is cut to half their width along the state the engine split (d), and the pieces
    ending alike grow nothing back; where they forked (nothing redone), the pieces' width was fine
    and d grows back as for clean pieces."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))

    def cut_and_settle(redone):
        a = pv.Adaptive(grade=4, rebox=False)
        a.needed.append((Box(("p", "d"), ((0.0, 0.125), (0.0, 0.125))), {"p": 0.125, "d": 0.125}))
        pieces = [c for c, _ in a.prepare(Box(("p", "d"), ((0.0, 0.5), (0.0, 0.5))), init)]
        for piece in pieces:
            deepest = 90 + round(piece.bounds[0][0] * 8)  # differ along p, alike along d
            a.learn(piece, _cell(piece, "verified", deepest_step=deepest, branches=1, steps_redone=redone, split="d"), init)
        nxt = [c if isinstance(c, Box) else c[0] for c in a.prepare(Box(("p", "d"), ((0.5, 0.75), (0.0, 0.25))), init)]
        return {(round(hi - lo, 6), round(dhi - dlo, 6)) for (lo, hi), (dlo, dhi) in (c.bounds for c in nxt)}

    assert cut_and_settle(60) == {(0.125, 0.0625)}
    assert cut_and_settle(0) == {(0.125, 0.25)}
    assert cut_and_settle(5) == {(0.125, 0.25)}  # a split where part arrived redoes a few steps
    assert cut_and_settle(40) == {(0.125, 0.25)}  # less than half a run (REDID)


def test_a_cut_piece_that_redid_steps_makes_the_rest_of_its_cut_smaller():
    """A 4 x 4 cut of a needed 1/8 x 1/8; its corner piece verifies only after a split along d
    that restarted from step 0. A piece of the same cut far from it is cut in two along d when
    drawn (its cut's shape was the one that failed), not only the pieces touching the corner."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(grade=4, rebox=False)
    a.needed.append((Box(("p", "d"), ((0.0, 0.125), (0.0, 0.125))), {"p": 0.125, "d": 0.125}))
    pieces = [c for c, _ in a.prepare(Box(("p", "d"), ((0.0, 0.5), (0.0, 0.5))), init)]
    corner = next(c for c in pieces if c.bounds[0][0] == 0.0 and c.bounds[1][0] == 0.0)
    far = next(c for c in pieces if c.bounds[0][0] == 0.375 and c.bounds[1][0] == 0.375)
    assert len(a.prepare(far, init)) == 1
    a.learn(corner, _cell(corner, "verified", deepest_step=95, branches=1, steps_redone=60, split="d"), init)
    halves = [c if isinstance(c, Box) else c[0] for c in a.prepare(far, init)]
    assert [(round(p[1] - p[0], 6), round(d[1] - d[0], 6)) for p, d in (c.bounds for c in halves)] == [(0.125, 0.0625)] * 2


def test_a_cell_at_min_width_is_retried_with_rebox_before_it_is_given_up():
    """Nothing can be halved: a plain cell lost with the call's splits runs once more reboxed
    (whatever the rebox trials near its size said), and then its verdict is final; with
    ``rebox=False`` it is final at once, unless it split inside: then it runs once more with
    ``DEEPEN`` times the splits it used up."""
    init = Box(("x",), ((0.0, 1.0),))
    cell = Box(("x",), ((0.0, 1 / 64),))
    lost = dict(steps_done=30, deepest_step=31, reason="step 31: 'x > 0' could not be proved")
    a = pv.Adaptive(min_width={"x": 1 / 64})
    for k in range(2):  # two retries at its size that did not pay: the rebox trials there are over
        a.retried[("trial", k)], a.tried[("trial", k)], a.paid[("trial", k)] = (30, 31, 6.0), 0, False
    assert a.rebox_score(init, 6.0) == (0, 2)
    a.learn(cell, _cell(cell, "unknown", **lost), init)
    assert a.again(cell, _cell(cell, "unknown", **lost), init, False) == Retry({"rebox": True})
    a.learn(cell, _cell(cell, "unknown", options={"rebox": True}, **lost), init)
    assert a.again(cell, _cell(cell, "unknown", options={"rebox": True}, **lost), init, False) is None
    b = pv.Adaptive(min_width={"x": 1 / 64}, rebox=False)
    assert b.again(cell, _cell(cell, "unknown", **lost), init, False) is None
    # A cell that used up 16 in-cell splits runs once more with four times as many, then is final.
    split = dict(lost, branches=16)
    assert b.again(cell, _cell(cell, "unknown", **split), init, False) == Retry({"max_splits": 64})
    deeper = _cell(cell, "unknown", options={"max_splits": 64}, **split)
    b.learn(cell, deeper, init)
    assert b.again(cell, deeper, init, False) is None


def test_a_cell_verified_after_halvings_that_gained_nothing_teaches_no_size():
    """p and d halved in turn, each gaining a step of ~95: the half that verifies has a size the
    path made by accident, and cutting its neighbours to it would spread it; after one such
    halving the size is learnt as before."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    for stalled, learnt in ((1, True), (2, False)):
        a = pv.Adaptive(rebox=False)
        cell, deepest = init, 40
        for k in range(stalled + 2):
            (cell, _), _ = _halve(a, cell, init, deepest, split="pd"[k % 2])
            deepest = 94 if k == 0 else deepest + 1
        a.learn(cell, _cell(cell, "verified", steps_done=deepest + 1, deepest_step=deepest + 1), init)
        assert bool(a.needed) == learnt


def test_a_rebox_decision_holds_for_cells_near_the_size_of_the_retries_that_made_it():
    """The whole set's retry paid (32 steps deeper against 2 for a halving): cells within two
    halvings of it run reboxed (after a plain trial at each size), smaller ones are plain until
    retries of cells their size decide
    (on Mountain Car the whole set's retry went twice as deep while cells eight halvings smaller
    verify plain)."""
    init = Box(("x",), ((0.0, 1.0),))
    a = pv.Adaptive(patience=2)
    assert a.again(init, _cell(init, "unknown", steps_done=33, deepest_step=33), init, False) == Retry({"rebox": True})
    deeper = _cell(init, "unknown", steps_done=65, deepest_step=65, split="x", options={"rebox": True})
    a.learn(init, deeper, init)
    (half, options), _ = a.again(init, deeper, init, False)
    a.learn(half, _cell(half, "unknown", steps_done=35, deepest_step=35, options=options), init)
    assert a.rebox_score(init) == (1, 0)

    def cell(k, i=0):  # the i-th cell of width 2^-k
        return Box(("x",), ((i / 2**k, (i + 1) / 2**k),))

    def unknown(c, deepest, **kwargs):
        return _cell(c, "unknown", steps_done=deepest, deepest_step=deepest, split="x", **kwargs)

    # Its halves' size has no plain run yet: they run plain, a trial; once one is lost, reboxed.
    assert not any(o.get("rebox") for _, o in a.again(cell(1, 1), unknown(cell(1, 1), 70, options={"rebox": True}), init, False))
    a.learn(cell(2, 2), unknown(cell(2, 2), 36), init)
    assert all(o.get("rebox") for _, o in a.again(cell(1, 1), unknown(cell(1, 1), 70, options={"rebox": True}), init, False))
    assert not any(o.get("rebox") for _, o in a.again(cell(4), unknown(cell(4), 70, options={"rebox": True}), init, False))
    # At a size no retry was made near, the first unknown cells are retried (two side by side),
    # the next halved plain.
    small = [cell(6, i) for i in range(3)]
    outs = [a.again(c, unknown(c, 80), init, False) for c in small]
    assert outs[:2] == [Retry({"rebox": True})] * 2 and not any(o.get("rebox") for _, o in outs[2])
    # Those retries gain a step where a plain halving of their size gains two: they lost, there.
    for c in small[:2]:
        a.learn(c, unknown(c, 81, options={"rebox": True}), init)
    a.learn(outs[2][0][0], unknown(outs[2][0][0], 82), init)
    assert a.rebox_score(init, 6) == (0, 2) and a.rebox_score(init, 0) == (1, 0)
    assert not any(o.get("rebox") for _, o in a.again(small[0], unknown(small[0], 81, options={"rebox": True}), init, False))
    assert a.again(cell(2, 3), unknown(cell(2, 3), 40), init, False) == Retry({"rebox": True})


def test_a_reboxed_retry_is_not_judged_by_the_halvings_of_cells_much_smaller_than_it():
    """The whole set's retry went 32 steps deeper; halving d there gained 31, and p was first
    halved plain five halvings further down, where halvings gain a step: against those the retry
    would pay, against its own size there is nothing to compare it with yet (lost)."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(learn_states=False, patience=8)

    def run(cell, deepest, split, options):
        """The cell's outcome learnt, its retry (no deeper) if the splitter asks for one; its first half."""
        out = _cell(cell, "unknown", steps_done=deepest, deepest_step=deepest, split=split, options=options)
        a.learn(cell, out, init)
        pieces = a.again(cell, out, init, False)
        if isinstance(pieces, Retry):
            out = replace(out, options={**options, **pieces.options})
            a.learn(cell, out, init)
            pieces = a.again(cell, out, init, False)
        return pieces[0]

    assert a.again(init, _cell(init, "unknown", steps_done=33, deepest_step=33), init, False) == Retry({"rebox": True})
    deeper = _cell(init, "unknown", steps_done=65, deepest_step=65, split="d", options={"rebox": True})
    a.learn(init, deeper, init)
    cell, options = a.again(init, deeper, init, False)[0]
    for deepest, split in ((64, "d"), (65, "d"), (66, "d"), (67, "d"), (68, "p")):
        cell, options = run(cell, deepest, split, options)
        assert not options.get("rebox")
    a.learn(cell, _cell(cell, "unknown", steps_done=68, deepest_step=68, options=options), init)
    assert a.gains == {"d": [31, 1, 1, 1, 1], "p": [0]}
    assert not a._rebox_won(_key(init), init)


@pytest.mark.parametrize(
    "grade, widths",
    [(2, [0.5, 0.25, 0.125, 1 / 16, 1 / 32, 1 / 64, 1 / 64]), (4, [0.25] * 3 + [1 / 16] * 3 + [1 / 64] * 4)],
)
def test_a_size_needed_on_one_side_of_a_wide_cell_cuts_it_finer_only_towards_that_side(grade, widths):
    """A cut makes at most ``grade`` pieces along a state (4 by default); the pieces that still
    touch the cells that needed the size are cut again when drawn, the others run as they are (a
    size needed at the Mountain Car wall had cut a cell 64 times as wide into 128 pieces)."""
    init = Box(("x", "y"), ((0.0, 2.0), (0.0, 1.0)))
    a = pv.Adaptive(grade=grade, rebox=False)
    needed = Box(("x", "y"), ((1.0, 1.0 + 1 / 64), (0.0, 1.0)))
    a.needed.append((needed, {"x": 1 / 64, "y": 1.0}))
    settled, todo = [], [Box(("x", "y"), ((0.0, 1.0), (0.0, 1.0)))]
    while todo:
        cell = todo.pop()
        pieces = a.prepare(cell, init)
        if pieces == [cell]:
            settled.append(cell)
        else:
            assert len(pieces) == grade
            todo += [piece for piece, _ in pieces]
    bounds = sorted(c.bounds[0] for c in settled)
    assert [hi - lo for lo, hi in bounds] == widths
    assert bounds[0][0] == 0.0 and bounds[-1][1] == 1.0 and all(p[1] == q[0] for p, q in zip(bounds, bounds[1:]))
    with pytest.raises(pv.InputError, match="grade"):
        pv.Adaptive(grade=1)


def test_a_state_a_cut_did_not_split_grows_from_the_pieces_of_other_cuts_beside_it():
    """Cuts of 4 x 1 along p (their d width is already the one needed): p differs piece to piece,
    and along d each piece ends like the piece of the cut below it. Those pairs across cuts say
    d's width did not matter: the next cell is cut twice as wide in d."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    a = pv.Adaptive(grade=4, rebox=False)
    a.needed.append((Box(("p", "d"), ((0.0, 0.125), (0.0, 0.125))), {"p": 0.125, "d": 0.125}))
    for k in range(2):
        pieces = [c for c, _ in a.prepare(Box(("p", "d"), ((0.0, 0.5), (k / 8, (k + 1) / 8))), init)]
        assert len(pieces) == 4
        for piece in pieces:
            deepest = 90 + round(piece.bounds[0][0] * 8)
            a.learn(piece, _cell(piece, "verified", steps_done=deepest, deepest_step=deepest, branches=1), init)
    nxt = [c if isinstance(c, Box) else c[0] for c in a.prepare(Box(("p", "d"), ((0.0, 0.5), (0.25, 0.5))), init)]
    assert {(round(p[1] - p[0], 6), round(d[1] - d[0], 6)) for p, d in (c.bounds for c in nxt)} == {(0.125, 0.25)}


def test_growth_evidence_is_pooled_over_cuts_of_two_pieces_and_outweighs_one_pair_that_differed():
    """Cuts of two pieces along p stacked along d, as at the Mountain Car wall: no cut holds
    GROW_PAIRS pairs along d, but together their pieces do, and d grows though one pair along it
    ended differently (it is outnumbered GROW_RATIO to one); p, whose pieces all differ, keeps its
    width. A lost cell as small as the grown shape beside the next cell keeps d too."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))

    def stacked(lost_beside=False):
        a = pv.Adaptive(grade=4, rebox=False)
        a.needed.append((Box(("p", "d"), ((0.0, 0.125), (0.0, 0.125))), {"p": 0.125, "d": 0.125}))
        for k in range(4):
            pieces = [c for c, _ in a.prepare(Box(("p", "d"), ((0.0, 0.25), (k / 8, (k + 1) / 8))), init)]
            assert len(pieces) == 2
            for piece in pieces:
                i = round(piece.bounds[0][0] * 8)
                deepest = 90 + i + (i == 0 and k == 0)  # the pair (i 0, k 0-1) along d differs
                a.learn(piece, _cell(piece, "verified", steps_done=deepest, deepest_step=deepest, branches=1), init)
        if lost_beside:
            lost = Box(("p", "d"), ((0.125, 0.25), (0.5, 0.75)))
            a.learn(lost, _cell(lost, "unknown", steps_done=50, deepest_step=50), init)
        nxt = [c if isinstance(c, Box) else c[0] for c in a.prepare(Box(("p", "d"), ((0.0, 0.25), (0.5, 1.0))), init)]
        return {(round(p[1] - p[0], 6), round(d[1] - d[0], 6)) for p, d in (c.bounds for c in nxt)}

    assert stacked() == {(0.125, 0.25)}
    assert stacked(lost_beside=True) == {(0.125, 0.125)}


@pytest.mark.parametrize("offset, width", [(1e6, 1e-3), (123456.789, 0.3), (0.0, 1e-13)])
def test_neighbours_made_by_a_cut_and_by_halvings_are_a_pair_far_from_zero_and_in_a_tiny_set(offset, width):
    """A state far from zero: a cut's piece and the half of a halving meet only up to their last
    bits, and a set narrower than rounded decimals would make all its cells one. Either way two
    cells side by side touch and are one pair, and a cell apart from them is in none."""
    init = Box(("x",), ((offset, offset + width),))
    a = pv.Adaptive(rebox=False)
    pieces = list(grid(init, {"x": 8})[0])
    cell, steps = init, 5
    for side in (1, 0, 1):  # halvings down to the eighth [5/8, 3/4] of the set
        cell, steps = a.again(cell, _cell(cell, "unknown", steps_done=steps, deepest_step=steps), init, False)[side][0], steps + 4
    assert pieces[4].bounds[0][1] < cell.bounds[0][0] or offset == 0.0  # the cut's face lies below the halving's, by last bits
    assert _touches(cell, pieces[4]) and _touches(pieces[4], cell) and not _touches(cell, pieces[3])
    for each in (pieces[0], cell, pieces[4]):
        a.learn(each, _cell(each, "verified", steps_done=20, deepest_step=20), init)
    assert len(a.pairs) == 1
    assert a.pairs.values[0].tolist() == [0, pytest.approx(width / 8), 1]


def test_a_lost_cell_whose_splits_restarted_is_halved_once_along_the_engines_state():
    """A cell lost after in-cell splits along d that redid 3 runs' steps (``REDONE``), or one given
    up at its ``max_redone``, is halved along d, whatever the probe prefers; once, however many
    runs' steps it redid (the engine's last split state need not be the one the cell is too wide
    in). One that redid less is halved along the probe's state."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    cell = Box(("p", "d"), ((0.0, 0.25), (0.0, 0.25)))

    def pieces(redone, reason="step 100: lost"):
        a = pv.Adaptive(grade=4, rebox=False)
        a.probe = lambda c, step: {"p": 1.0, "d": 0.0}
        lost = _cell(cell, "unknown", steps_done=40, deepest_step=100, branches=16, steps_redone=redone, split="d", reason=reason)
        a.learn(cell, lost, init)
        return sorted(
            (round(p[1] - p[0], 6), round(d[1] - d[0], 6), d[0]) for p, d in (c.bounds for c, _ in a.again(cell, lost, init, False))
        )

    along_d = [(0.25, 0.125, 0.0), (0.25, 0.125, 0.125)]
    assert pieces(300) == along_d
    assert pieces(1500) == along_d
    assert pieces(5) == [(0.125, 0.25, 0.0)] * 2
    assert pieces(100) == [(0.125, 0.25, 0.0)] * 2  # a run's steps: arrivals split, say
    assert pieces(150, reason="step 100: lost (after 2 splits; the next would compute steps again past max_redone)") == along_d


def test_a_plain_cell_given_up_at_its_max_redone_does_not_count_as_a_plain_loss_for_rebox():
    """Plain cells of a size lost more often than not (with retries near it that paid) make cells
    of that size run reboxed; a cell given up before a split past its ``max_redone`` is not such a
    loss (it asks for halving), unless no other plain cell of its size ran: then two of them are."""
    init = Box(("x",), ((0.0, 1.0),))
    cell = Box(("x",), ((0.0, 0.25),))
    given_up = "step 9: lost (after 3 splits; the next would compute steps again past max_redone)"
    for reason, counted in (("step 9: lost", [0, 1, 0]), (given_up, [0, 0, 1])):
        a = pv.Adaptive()
        a.learn(cell, _cell(cell, "unknown", options={"max_redone": REDONE}, steps_done=9, deepest_step=9, reason=reason), init)
        assert a.plain.get(2.0) == counted
    b = pv.Adaptive()
    b.retried[("retry",)], b.tried[("retry",)], b.paid[("retry",)] = (9, 9, 2.0), 11, True
    for other in (Box(("x",), ((0.25, 0.5),)), cell):
        assert not b._reboxing(2.0, init)
        b.learn(other, _cell(other, "unknown", options={"max_redone": REDONE}, steps_done=9, deepest_step=9, reason=given_up), init)
    assert b._reboxing(2.0, init)
    verified = Box(("x",), ((0.5, 0.75),))
    b.learn(verified, _cell(verified, "verified", steps_done=20, deepest_step=20), init)
    assert not b._reboxing(2.0, init)


def test_a_cell_that_redid_many_runs_teaches_a_halving_per_doubling_of_them():
    """A cell verified after splits that restarted from step 0: steps of under half a run teach
    no halving (``REDID``: halving would add a run to every cell like it, such splits 1.4 runs to
    those that split), of half a run to 4 runs one halving along the state split most, of 8-15
    runs three (it was as costly as 8-16 cells)."""
    init = Box(("p", "d"), ((0.0, 1.0), (0.0, 1.0)))
    cell = Box(("p", "d"), ((0.0, 0.25), (0.0, 0.25)))
    learnt = {}
    for redone in (40, 60, 150, 1300):
        a = pv.Adaptive(rebox=False)
        a.lineage[_key(cell)] = (-1, -1, 0, "p", ())
        a.learn(cell, _cell(cell, "verified", deepest_step=100, branches=3, steps_redone=redone, split="d"), init)
        learnt[redone] = a.needed[-1][1]
    assert learnt == {
        40: {"p": 0.25, "d": 0.25},
        60: {"p": 0.25, "d": 0.125},
        150: {"p": 0.25, "d": 0.125},
        1300: {"p": 0.25, "d": 0.25 / 8},
    }


def test_the_adaptive_default_makes_the_same_cells_whichever_finishes_first(monkeypatch):
    """Cells that finish in another order (random delays after each engine run, on 1 to 3
    threads) leave the splitter with the same knowledge at each draw: the same cells, the same
    verdicts (with 2 workers, finish order had made 24 to 1,939 cells of one call)."""
    from percver.verification import campaign

    run = campaign.run_cells
    rng = np.random.default_rng()

    def delayed(problem, cells, done, options, workers, progress=None):
        def late(i, outcome, rss):
            time.sleep(rng.uniform(0.0, 0.03))
            done(i, outcome, rss)

        run(problem, cells, late, options, workers, progress)

    monkeypatch.setattr(campaign, "run_cells", delayed)
    loop, kwargs = _wall_problem()
    kwargs["init"] = {"p": (-0.44, -0.40), "v": (-0.004, 0.004)}
    made = []
    for workers in (1, 2, 3, 2):
        result = pv.verify(loop, workers=workers, **kwargs)
        made.append(sorted((c.box["p"], c.box["v"], c.verdict, c.steps_done, c.options.get("rebox", False)) for c in result.cells))
    assert len(made[0]) > 8
    assert all(m == made[0] for m in made[1:])


def test_a_run_that_stops_journals_every_cell_that_finished(monkeypatch, tmp_path):
    """Outcomes wait for earlier draws' before they are learnt; when a cell's run fails, the cells
    drawn after it that finished on the other thread are journaled all the same, and a rerun
    resumes without running them again."""
    from percver.verification import campaign

    run = campaign.run_cells
    calls, finished, lock = [0], [], threading.Lock()

    def failing(problem, cells, done, options, workers, progress=None):
        with lock:
            # The first run of a half: the whole set's retries run alone.
            calls[0] += tuple(cells[0][0]) != (-0.44, -0.40)
            mine = calls[0]
        if mine == 1:
            time.sleep(1.5)
            raise RuntimeError("the worker broke")

        def noted(i, outcome, rss):
            finished.append(tuple(cells[i]))
            done(i, outcome, rss)

        run(problem, cells, noted, options, workers, progress)

    monkeypatch.setattr(campaign, "run_cells", failing)
    loop, kwargs = _wall_problem()
    kwargs["init"] = {"p": (-0.44, -0.40), "v": (-0.004, 0.004)}
    journal = tmp_path / "run.jsonl"
    with pytest.raises(RuntimeError, match="the worker broke"):
        pv.verify(loop, workers=2, journal=journal, **kwargs)
    later = len(finished)
    assert later >= 3  # cells drawn after the failed one finished meanwhile
    journaled = {tuple(tuple(b) for b in c.box.values()) for c in journal_cells(journal)}
    assert {tuple(tuple(b) for b in cell) for cell in finished} <= journaled
    monkeypatch.setattr(campaign, "run_cells", run)
    result = pv.verify(loop, workers=2, journal=journal, **kwargs)
    assert result.verdict == "verified"


class _Reopening(pv.Grid):
    """One cell, given up, then taken back once everything is settled: halved in p."""

    reopened: list = []

    def revisit(self, init):
        if _Reopening.reopened:
            return []
        _Reopening.reopened.append(init)
        (lo, hi) = init.bounds[0]
        return [(init, [(Box(init.names, ((lo, mid), *init.bounds[1:])), {}) for lo, mid in ((lo, (lo + hi) / 2), ((lo + hi) / 2, hi))])]


def test_a_cell_the_splitter_takes_back_is_replaced_by_its_pieces(tmp_path):
    """A splitter's ``revisit`` (run when every drawn cell is settled) replaces a settled cell by
    its pieces: the result holds the pieces, not the cell, and a resumed run makes the same."""
    loop, kwargs = _wall_problem()
    _Reopening.reopened.clear()
    result = pv.verify(loop, splitter=_Reopening(), journal=tmp_path / "j.jsonl", **kwargs)
    mid = (-0.42 + -0.40) / 2
    assert sorted(c.box["p"] for c in result.cells) == [(-0.42, mid), (mid, -0.4)]
    _Reopening.reopened.clear()
    again = pv.verify(loop, splitter=_Reopening(), journal=tmp_path / "j.jsonl", **kwargs)
    assert [(c.box, c.verdict) for c in again.cells] == [(c.box, c.verdict) for c in result.cells]
