"""What to try after an unknown verdict (``Result.hints``): each hint found on a real unknown cell,
and the run with its keywords decides what the run without them left unknown."""

import warnings
from dataclasses import replace

import pytest

import percver as pv
from closed_loops import CASES
from percver.commands.verify import report
from percver.verification.results import Cell, Result
from test_state_symbols_continuous import loop as oscillator
from test_verify import mountain_car


def test_a_loose_growing_enclosure_hints_symbols_and_rebox_and_each_verifies():
    """A ReLU-controlled oscillator at order 3 in one cell without splits: the float runs contract,
    while the enclosure grows about twice a step from its own fed-back errors until step 17."""
    loop = oscillator()
    kwargs = dict(steps=40, safe=pv.Box({"x": (-2, 2)}), order=3, max_splits=0, splitter=pv.Grid(), progress=False)
    init = {"x": (0.6, 0.65), "v": (-0.3, -0.25)}
    plain = pv.verify(loop, init, **kwargs)
    assert plain.verdict == "unknown"
    hints = plain.hints(loop)
    assert [h.keywords for h in hints] == [{"state_symbols": True}, {"rebox": True}], hints
    assert "wrapping" in hints[0].why and hints[0].cells == 1
    for hint in hints:
        assert pv.verify(loop, init, **{**kwargs, **hint.keywords}).verdict == "verified", hint
    # Without the loop there are no float runs to compare with: nothing is claimed about looseness.
    assert plain.hints() == []
    with pytest.raises(pv.InputError, match=r"hints\(loop=\.\.\.\) takes the pv.ClosedLoop .*, got str"):
        plain.hints("loop.py")
    # The command line prints them under the unknown cells.
    assert "try: state_symbols=True: the enclosure of " in report(plain, loop)
    # Cells a time limit left out carry no boxes: the evidence is looked for past them.
    unrun = [Cell(plain.cells[0].box, "unknown", reason="not run within time_limit=1 s") for _ in range(20)]
    limited = Result(plain.states, plain.init, unrun + plain.cells, plain.seconds, {**plain.settings, "time_limit": 1.0})
    assert [h.keywords for h in limited.hints(loop)] == [{"time_limit": 4.0}, {"state_symbols": True}, {"rebox": True}]
    # A cell that ran with state symbols already (the adaptive splitter's choice) does not ask for them.
    (cell,) = plain.cells
    symbolic = Result(plain.states, plain.init, [replace(cell, options={**cell.options, "state_symbols": True})], 0.0, plain.settings)
    assert [h.keywords for h in symbolic.hints(loop)] == [{"rebox": True}]


def test_cells_the_splitter_replaced_are_evidence_when_those_left_carry_none():
    """Under a time limit the adaptive splitter's cells left are mostly not run, while the cells it
    halved (kept in ``Result.lost``, the first 16) show the wrapping; they survive the JSON."""
    loop = oscillator()
    kwargs = dict(steps=40, safe=pv.Box({"x": (-2, 2)}), order=3, max_splits=0, progress=False, workers=2)
    init = {"x": (0.6, 0.65), "v": (-0.3, -0.25)}
    limited = pv.verify(loop, init, splitter=pv.Adaptive(rebox=False, symbols=False), time_limit=1.0, **kwargs)
    assert limited.verdict == "unknown" and 0 < len(limited.lost) <= 16
    assert all(c.verdict == "unknown" and len(c.boxes) > 1 for c in limited.lost)
    # Only the replaced cells carry boxes here: the hints must come from them.
    unrun = [Cell(c.box, "unknown", reason="not run within time_limit=1 s") for c in limited.cells]
    bare = Result(limited.states, limited.init, unrun, limited.seconds, limited.settings, lost=limited.lost)
    hints = bare.hints(loop)
    assert [h.keywords for h in hints] == [{"time_limit": 4.0}, {"state_symbols": True}, {"rebox": True}], hints
    assert "a cell the splitter then replaced" in hints[1].why
    again = Result.from_json(bare.to_json())
    assert [c.box for c in again.lost] == [c.box for c in limited.lost] and [h.why for h in again.hints(loop)] == [h.why for h in hints]
    assert pv.verify(loop, init, state_symbols=True, **kwargs).verdict == "verified"


def test_splits_used_up_hint_more_of_them_and_that_verifies():
    """A Mountain Car cell whose runs reach the goal over several steps near the wall: 16 in-cell
    splits and forks are not enough, 64 are."""
    loop, p, _ = mountain_car()
    kwargs = dict(init={"p": (-0.42, -0.40), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, progress=False, splitter=pv.Grid())
    result = pv.verify(loop, max_splits=16, **kwargs)
    assert result.verdict == "unknown"
    (hint,) = result.hints(loop)
    assert hint.keywords == {"max_splits": 64} and "reach the goal at different steps" in hint.why
    assert pv.verify(loop, **{**kwargs, **hint.keywords}).verdict == "verified"


def test_an_operation_out_of_its_domain_hints_rebox():
    """Verisig 2.0's F1/10 benchmark as one cell, plain: a division by a range containing zero at
    step 31 (the issue a new user met: nothing suggested rebox). That one cell reboxed verifies:
    ``test_verisig_suite.py::test_f1tenth_verifies_at_the_defaults``, where the adaptive default
    retries it so."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        problem, _ = CASES["verisig_f1tenth_reboxed"]()
    plain = problem.verify(progress=False, splitter=pv.Grid())
    assert plain.verdict == "unknown" and "undefined" in plain.cells[0].reason
    hints = plain.hints(problem)
    assert hints[0].keywords == {"rebox": True}, hints


def test_decided_results_and_cells_without_evidence_get_no_hints():
    box = {"x": (0.0, 1.0)}
    cell = lambda verdict, reason=None, **kw: Cell(box, verdict, reason=reason, **kw)  # noqa: E731
    settings = {"max_splits": 16, "rebox": False, "timeout_per_cell": None}
    assert Result(["x"], box, [cell("verified")], settings=settings).hints() == []
    assert Result(["x"], box, [cell("falsified"), cell("unknown", "step 3: blew up")], settings=settings).hints() == []
    # Splits left over, or none allowed: no claim that more would help.
    assert Result(["x"], box, [cell("unknown", "step 9: 'x <= 1' could not be decided (after 3 splits)")], settings=settings).hints() == []
    given = {**settings, "max_splits": 0}
    assert Result(["x"], box, [cell("unknown", "step 9: 'x <= 1' could not be decided")], settings=given).hints() == []
    # Already reboxed: rebox is not suggested again; a timeout is.
    reboxed = {**settings, "rebox": True, "timeout_per_cell": 2.0}
    cells = [cell("unknown", "step 4: the enclosure of 'x' blew up (inf)"), cell("unknown", "timeout after 2 s at step 7")]
    (hint,) = Result(["x"], box, cells, settings=reboxed).hints()
    assert hint.keywords == {"timeout_per_cell": 8.0} and hint.cells == 1


@pytest.mark.parametrize("reason", ["division is undefined on [-1, 1]", "the enclosure of 'x' blew up (inf)"])
def test_lost_precision_without_rebox_hints_it(reason):
    box = {"x": (0.0, 1.0)}
    result = Result(["x"], box, [Cell(box, "unknown", reason=f"step 5: {reason}")], settings={"max_splits": 16, "rebox": False})
    assert [h.keywords for h in result.hints()] == [{"rebox": True}]
    # A cell the adaptive default already retried reboxed says nothing for rebox.
    retried = Result(["x"], box, [Cell(box, "unknown", reason=f"step 5: {reason}", options={"rebox": True})], settings=result.settings)
    assert retried.hints() == []
