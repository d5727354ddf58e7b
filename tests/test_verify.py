"""Closed-loop verification: sampling oracle, falsification, journal resume, bad input."""

import json
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import percver as pv

from percver.verification import campaign
from percver.verification.splitters import bisect

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CONTROLLER = DATA / "mountain_car" / "networks" / "ControllerSigmoid16x16.yml"


def mountain_car():
    """The state-based Mountain Car loop of REFERENCE.md with the authors' sig16x16 controller."""
    assert CONTROLLER.exists(), f"{CONTROLLER} missing: CI has ../shared beside the repo"
    p, v = pv.variables("p v")
    u = pv.variables("u")
    v_next = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    p_next = p + v_next
    plant = pv.Discrete({p: pv.where(p_next <= -1.2, -1.2, p_next), v: pv.where(p_next <= -1.2, 0.0, v_next)}, inputs=[u])
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(pv.load_network(str(CONTROLLER)), inputs=[p, v], output="u")])
    return loop, p, v


def assert_contains_simulations(loop, result, n=1000, seed=1, goal_p=None):
    """Every simulated state lies in its step's reach box; with a `within` goal p >= goal_p, up to
    the step at which the run met it (its part of the boxes ends there)."""
    for cell in result.cells:
        if not cell.boxes:
            continue
        boxes = np.asarray(cell.boxes)
        x0 = pv.Box.coerce(cell.box, loop.states).sample(n, seed=seed)
        traj = loop.simulate(x0, len(boxes) - 1)
        inside = ((traj >= boxes[None, :, :, 0]) & (traj <= boxes[None, :, :, 1])).all(axis=2)
        if goal_p is not None:
            met = np.cumsum(traj[:, :, loop.states.index("p")] >= goal_p, axis=1) > 0
            inside |= np.concatenate([np.zeros_like(met[:, :1]), met[:, :-1]], axis=1)
        assert inside.all(), f"cell {cell.box}: {np.count_nonzero(~inside)} simulated states outside the reach boxes"


@pytest.mark.parametrize("state_symbols", [False, True])
def test_mountain_car_verified_and_reach_boxes_contain_simulations(state_symbols):
    loop, p, v = mountain_car()
    res = pv.verify(
        loop,
        init={"p": (-0.53, -0.50), "v": (0, 0)},
        steps=150,
        goal=p >= 0.45,
        within=True,
        split={"p": 3},
        state_symbols=state_symbols,
        progress=False,
    )
    assert res.verdict == "verified", [c.reason for c in res.cells]
    assert res.coverage == pytest.approx(1.0)
    assert_contains_simulations(loop, res)
    assert "intervals" in res.summary()
    back = pv.Result.from_json(res.to_json())
    assert back.verdict == "verified" and len(back.cells) == 3


def test_safety_property_and_unsafe_set():
    loop, p, v = mountain_car()
    res = pv.verify(loop, init={"p": (-0.5, -0.49), "v": (0, 0)}, steps=40, safe=[v >= -0.07, v <= 0.07], unsafe=p <= -1.3, progress=False)
    assert res.verdict == "verified"
    assert_contains_simulations(loop, res, n=300)


def test_known_unsafe_start_is_falsified_with_a_replaying_counterexample():
    loop, p, v = mountain_car()
    res = pv.verify(loop, init={"p": (-0.6, -0.6), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, progress=False)
    assert res.verdict == "falsified"
    cex = res.counterexample
    replay = loop.simulate(np.array([[cex.initial["p"], cex.initial["v"]]]), 150)[0]
    assert replay[:, 0].max() < 0.45
    np.testing.assert_allclose(np.asarray(cex.trajectory), replay[: cex.step + 1])


def test_falsification_ends_a_run_at_its_goal_as_the_engine_does():
    # x climbs by 1 a step from [0, 0.5]: at the goal x >= 3 by step 3, beyond x <= 5 from step 5.
    # With within=True a run's part ends at its goal, so the later breach is no counterexample
    # (simulating past the goal once reported one here); with the goal at the last step it is.
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 1.0}))
    arrive = pv.verify(loop, init={"x": (0.0, 0.5)}, steps=10, safe=x <= 5, goal=x >= 3, within=True, progress=False)
    assert arrive.verdict == "verified"
    end = pv.verify(loop, init={"x": (0.0, 0.5)}, steps=10, safe=x <= 5, goal=x >= 3, within=False, progress=False)
    assert end.verdict == "falsified"
    cex = end.counterexample
    assert cex.step == 5 and cex.trajectory[-1][0] > 5 and "x <= 5" in cex.violated


def test_cells_the_engine_cannot_verify_are_sampled_and_verified_ones_are_not(monkeypatch):
    # Safe unless x is in (0.2, 0.4) at step 0: the centre (0.5) and corners (0, 1) of the cell
    # [0, 1] pass, the engine cannot verify it, and random runs find the gap. The cells [2, 3] and
    # [4, 5] verify: they are probed (centre and corners), never sampled at random.
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 10.0}))
    sampled = []
    falsify = campaign.falsify

    def spy(loop_, prop, cells, steps, samples, seed, probe=True):
        sampled.extend((c.bounds[0], samples, probe) for c in cells)
        return falsify(loop_, prop, cells, steps, samples, seed, probe)

    monkeypatch.setattr(campaign, "falsify", spy)
    res = pv.verify(loop, init={"x": (0.0, 5.0)}, split={"x": 5}, steps=3, safe=(x - 0.3) ** 2 >= 0.01, workers=1, progress=False)
    verdicts = {c.box["x"]: c.verdict for c in res.cells}
    assert verdicts[(0.0, 1.0)] == "falsified" and verdicts[(2.0, 3.0)] == verdicts[(4.0, 5.0)] == "verified"
    first = next(c for c in res.cells if c.box["x"] == (0.0, 1.0))
    assert 0.2 < first.counterexample.initial["x"] < 0.4 and first.seconds > 0
    assert "the engine:" in first.reason
    assert all(probe and samples == 0 for _, samples, probe in sampled[:5])
    randomly = {bounds for bounds, samples, probe in sampled if not probe}
    assert (0.0, 1.0) in randomly and not randomly & {(2.0, 3.0), (4.0, 5.0)}


def test_cells_falsified_in_batches_add_up(tmp_path):
    # 200 cells on one worker, which falsifies a batch (STOCK cells) whenever it has none ready.
    # Every cell is settled once, in the result and in the journal, with the verdict its position
    # asks for: falsified exactly where a corner passes 12.02 at step 5.
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 1.0}))
    journal = tmp_path / "chunks.jsonl"
    res = pv.verify(
        loop, init={"x": (0.0, 10.0)}, split={"x": 200}, steps=5, safe=x <= 12.02, workers=1, progress=False, journal=str(journal)
    )
    boxes = sorted(c.box["x"] for c in res.cells)
    assert len(boxes) == 200 and all(a[1] == pytest.approx(b[0]) for a, b in zip(boxes, boxes[1:]))
    assert all(c.verdict == ("falsified" if c.box["x"][1] + 5 > 12.02 else "verified") for c in res.cells)
    assert len(journal.read_text().splitlines()) == 1 + 200


def test_unknown_cells_are_refined(tmp_path):
    loop, p, v = mountain_car()
    # Order 2 loses precision on the wide cell, and no in-cell splits are allowed; refinement
    # splits until cells verify.
    kwargs = dict(
        init={"p": (-0.53, -0.45), "v": (0, 0)},
        steps=150,
        goal=p >= 0.45,
        within=True,
        order=2,
        max_splits=0,
        refine=True,
        min_width={"p": 0.005},
        progress=False,
        journal=str(tmp_path / "refine.jsonl"),
    )
    res = pv.verify(loop, **kwargs)
    assert len(res.cells) > 1
    assert all(c.verdict in ("verified", "unknown") for c in res.cells)
    widths = [c.box["p"][1] - c.box["p"][0] for c in res.cells]
    assert sum(widths) == pytest.approx(0.08)
    assert_contains_simulations(loop, res, n=200)
    # A rerun takes everything from the journal, refined parents included, and runs nothing.
    size = (tmp_path / "refine.jsonl").stat().st_size
    again = pv.verify(loop, **kwargs)
    assert sorted(c.box["p"] for c in again.cells) == sorted(c.box["p"] for c in res.cells)
    assert (tmp_path / "refine.jsonl").stat().st_size == size


def test_refinement_halves_the_state_the_engine_needed(tmp_path):
    # A parameter w that the dynamics never read is as wide (relative to the initial set) as p.
    # Splitting it cannot help: cells are split along p, in the engine and in refinement alike.
    p, v, w = pv.variables("p v w")
    u = pv.variables("u")
    v_next = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    p_next = p + v_next
    plant = pv.Discrete({p: pv.where(p_next <= -1.2, -1.2, p_next), v: pv.where(p_next <= -1.2, 0.0, v_next), w: w}, inputs=[u])
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(pv.load_network(str(CONTROLLER)), inputs=[p, v], output="u")])
    journal = tmp_path / "hint.jsonl"
    res = pv.verify(
        loop,
        init={"p": (-0.58, -0.42), "v": (0, 0), "w": (0, 1)},
        steps=150,
        goal=p >= 0.45,
        within=True,
        order=2,
        refine=True,
        min_width={"p": 0.005},
        progress=False,
        journal=str(journal),
    )
    assert res.verdict == "verified"
    assert all(c.box["w"] == (0.0, 1.0) for c in res.cells)
    parents = [json.loads(line) for line in journal.read_text().splitlines()[1:]]
    assert [c["split"] for c in parents if c["verdict"] == "unknown"] and all(
        c["split"] == "p" for c in parents if c["verdict"] == "unknown"
    )
    assert_contains_simulations(loop, res, n=200, goal_p=0.45)


def test_parts_share_one_pool_with_their_own_grids_orders_and_journals(tmp_path):
    # Part a (order 2, no in-cell split) leaves its cell unknown and is refined into halves while
    # part b's cells (order 5, a grid of 3) run on the other thread: each part keeps its own cells,
    # settings and journal, and the cells' verdicts and reach boxes are those of verify() on each
    # part alone (a cell's run does not depend on the pool).
    loop, p, v = mountain_car()
    common = dict(steps=150, goal=p >= 0.45, within=True, refine=True, min_width={"p": 0.005}, progress=False)
    a = pv.Part({"p": (-0.53, -0.45), "v": (0, 0)}, order=2, max_splits=0, journal=str(tmp_path / "a.jsonl"))
    b = pv.Part({"p": (-0.45, -0.42), "v": (0, 0)}, split={"p": 3}, journal=str(tmp_path / "b.jsonl"))
    both = pv.verify_parts(loop, [a, b], workers=2, **common)
    alone = [pv.verify(loop, part.init, split=part.split, order=part.order, max_splits=part.max_splits, **common) for part in (a, b)]
    for got, want, part in zip(both, alone, (a, b)):
        assert got.settings["order"] == part.order and got.init["p"] == part.init["p"]
        cells = {c.box["p"]: (c.verdict, c.boxes) for c in got.cells}
        assert cells == {c.box["p"]: (c.verdict, c.boxes) for c in want.cells}
        assert sum(hi - lo for lo, hi in cells) == pytest.approx(part.init["p"][1] - part.init["p"][0])
        journal = [json.loads(line) for line in Path(part.journal).read_text().splitlines()[1:]]
        assert {tuple(c["box"]["p"]) for c in journal} >= set(cells)
        assert_contains_simulations(loop, got, n=200, goal_p=0.45)
    assert len(both[0].cells) > 1 and len(both[1].cells) == 3
    assert both[0].seconds == both[1].seconds  # one call: each result has its wall time


def test_an_error_in_a_pool_thread_reaches_the_caller_and_closes_the_journals(tmp_path, monkeypatch):
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 1.0}))
    calls = []

    def broken(*args, **kwargs):
        calls.append(threading.current_thread().name)
        raise RuntimeError("simulation failed")

    monkeypatch.setattr(campaign, "falsify", broken)
    parts = [pv.Part({"x": (0.0, 1.0)}, split={"x": 40}, journal=str(tmp_path / f"{k}.jsonl")) for k in range(2)]
    with pytest.raises(RuntimeError, match="simulation failed"):
        pv.verify_parts(loop, parts, steps=3, safe=x <= 100.0, workers=2, progress=False)
    assert calls and not list(tmp_path.glob("*.lock"))


def test_the_progress_bar_counts_the_verdicts_of_all_parts(capsys):
    # x + 3 <= 4.5 from x in [0, 1] (4 cells, verified) and [1, 2] (3 cells: [1, 4/3] verified,
    # the others falsified): the bar's last line has the verdicts of both parts together.
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 1.0}))
    parts = [pv.Part({"x": (0.0, 1.0)}, split={"x": 4}), pv.Part({"x": (1.0, 2.0)}, split={"x": 3})]
    first, second = pv.verify_parts(loop, parts, steps=3, safe=x <= 4.5, workers=2)
    assert [len(first.cells), len(second.cells)] == [4, 3] and first.verdict == "verified"
    last = capsys.readouterr().err.split("\r")[-1]
    assert "7/7" in last and "verified=5, unknown=0, falsified=2" in last, last


def test_verify_parts_rejects_what_is_not_a_part():
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: x + 1.0}))
    with pytest.raises(pv.InputError, match="at least one"):
        pv.verify_parts(loop, [], steps=3, safe=x <= 100.0)
    with pytest.raises(pv.InputError, match=r"part 0 is a dict; give pv.Part\(init="):
        pv.verify_parts(loop, [{"init": {"x": (0, 1)}}], steps=3, safe=x <= 100.0)
    with pytest.raises(pv.InputError, match="workers must be a positive integer"):
        pv.verify_parts(loop, [pv.Part({"x": (0, 1)})], steps=3, safe=x <= 100.0, workers=0, progress=False)
    # A part's own keywords (and typos) are not verify_parts' keywords; the others are verify's.
    with pytest.raises(TypeError, match=r"unexpected keyword arguments \['order', 'stpes'\]; it takes steps, goal, "):
        pv.verify_parts(loop, [pv.Part({"x": (0, 1)})], stpes=3, order=4, safe=x <= 100.0)


def test_a_wall_hit_at_different_steps_forks_the_plant():
    # From p0 in [-0.41, -0.40] every run hits the left wall (p = -1.2, v reset to 0), at one of
    # five steps. The hull of both sides of the wall loses the cell; forking the plant's guard
    # (one branch per side, both `where`s on it take the same side) keeps every branch precise.
    loop, p, v = mountain_car()
    kwargs = dict(
        init={"p": (-0.41, -0.40), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, progress=False, splitter=pv.Grid()
    )  # one cell: the engine's own forks and splits are under test
    hull = pv.verify(loop, max_splits=0, **kwargs)
    forked = pv.verify(loop, max_splits=8, **kwargs)
    assert hull.verdict == "unknown" and forked.verdict == "verified"
    assert 1 <= forked.cells[0].branches <= 8
    # Twice as wide it stays unknown with parts still waiting: its boxes stop where they stop
    # being complete (they held only the parts that had run, up to the step it gave up).
    wide = pv.verify(loop, max_splits=16, **{**kwargs, "init": {"p": (-0.42, -0.40), "v": (0, 0)}})
    assert wide.verdict == "unknown" and wide.cells[0].steps_done == len(wide.cells[0].boxes) - 1
    # Its deepest step is where a part gave up, the step its reason names, past the boxes' end.
    cell = wide.cells[0]
    assert cell.reason.startswith(f"step {cell.deepest_step}:") and cell.deepest_step > cell.steps_done, (cell.reason, cell.steps_done)
    # The same with the states' errors as symbols (the wall's exact point has none).
    symbols = pv.verify(loop, max_splits=8, state_symbols=True, **kwargs)
    assert symbols.verdict == "verified"
    for res in (hull, forked, wide, symbols):
        assert_contains_simulations(loop, res, n=2000, goal_p=0.45)


def test_bisection_hint_yields_to_min_width():
    init = pv.Box.coerce({"p": (0.0, 1.0), "w": (0.0, 1.0)}, ["p", "w"])
    cell = pv.Box.coerce({"p": (0.0, 0.01), "w": (0.0, 0.5)}, ["p", "w"])
    halves = bisect(cell, init, {"p": 0.005}, hint="p")
    assert [h.bounds for h in halves] == [((0.0, 0.01), (0.0, 0.25)), ((0.0, 0.01), (0.25, 0.5))]
    halves = bisect(cell, init, {"p": 0.001}, hint="p")
    assert [h.bounds for h in halves] == [((0.0, 0.005), (0.0, 0.5)), ((0.005, 0.01), (0.0, 0.5))]


def test_verisig_method_agrees_on_a_short_horizon():
    loop, p, v = mountain_car()
    a = pv.verify(loop, init={"p": (-0.52, -0.51), "v": (0, 0)}, steps=5, safe=p >= -1.2, progress=False, method="taylor")
    b = pv.verify(loop, init={"p": (-0.52, -0.51), "v": (0, 0)}, steps=5, safe=p >= -1.2, progress=False, method="verisig")
    assert a.verdict == b.verdict == "verified"
    assert_contains_simulations(loop, b, n=300)


def test_journal_resume_after_sigkill(tmp_path):
    journal = tmp_path / "run.jsonl"
    script = tmp_path / "campaign.py"
    script.write_text(
        textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_verify import mountain_car
        import percver as pv
        loop, p, v = mountain_car()
        pv.verify(loop, init={{"p": (-0.55, -0.45), "v": (0, 0)}}, steps=150, goal=p >= 0.45, within=True,
                  split={{"p": 60}}, journal={str(journal)!r}, progress=False, workers=1)
    """)
    )
    proc = subprocess.Popen([sys.executable, str(script)])
    deadline = time.time() + 120
    while time.time() < deadline:
        if journal.exists() and len(journal.read_text().splitlines()) >= 6:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    lines_before = len(journal.read_text().splitlines()) - 1
    assert 5 <= lines_before < 60, "the campaign must be killed mid-way"
    loop, p, v = mountain_car()
    kwargs = dict(init={"p": (-0.55, -0.45), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, split={"p": 60}, progress=False)
    resumed = pv.verify(loop, journal=str(journal), **kwargs)
    clean = pv.verify(loop, **kwargs)
    key = lambda c: c.box["p"]  # noqa: E731
    assert [c.verdict for c in sorted(resumed.cells, key=key)] == [c.verdict for c in sorted(clean.cells, key=key)]
    records = [json.loads(line) for line in journal.read_text().splitlines()[1:] if line.strip()]
    boxes = [tuple(r["box"]["p"]) for r in records]
    assert len(boxes) == len(set(boxes)) == 60, "every cell journaled exactly once"
    # A journal of another problem is refused.
    with pytest.raises(pv.PercverError, match="different problem"):
        pv.verify(loop, journal=str(journal), **{**kwargs, "steps": 149})


class TestBadInput:
    def test_wiring_and_names(self):
        loop, p, v = mountain_car()
        ctrl = pv.load_network(str(CONTROLLER))
        x = pv.variables("x")
        with pytest.raises(pv.InputError, match="takes 2 inputs"):
            pv.ClosedLoop(pv.Discrete({p: p}, inputs=[]), stages=[pv.Stage(ctrl, inputs=[p], output="u")])
        with pytest.raises(pv.InputError, match="'w'"):
            pv.ClosedLoop(pv.Discrete({p: p}), stages=[pv.Stage(ctrl, inputs=[p, "w"], output="u")])
        with pytest.raises(pv.InputError, match="not produced"):
            pv.ClosedLoop(pv.Discrete({p: p + x}, inputs=[x]))
        with pytest.raises(pv.InputError, match="not states"):
            pv.verify(loop, init={"p": (0, 0.1), "v": (0, 0)}, steps=3, goal=x >= 1, progress=False)
        with pytest.raises(pv.InputError, match="missing"):
            pv.verify(loop, init={"p": (0, 0.1)}, steps=3, goal=p >= 1, progress=False)
        with pytest.raises(pv.InputError, match="lower bound"):
            pv.verify(loop, init={"p": (0.1, 0), "v": (0, 0)}, steps=3, goal=p >= 1, progress=False)
        with pytest.raises(pv.InputError, match="nothing to verify"):
            pv.verify(loop, init={"p": (0, 0.1), "v": (0, 0)}, steps=3, progress=False)


def test_continuous_plant_with_network_controller():
    """x' = v, v' = u - 0.1 v with u from a small tanh network held over each 0.1 s period."""
    from percver.networks import Layer, Network

    x, v = pv.variables("x v")
    u = pv.variables("u")
    net = Network(
        [
            Layer(np.array([[-0.8, -1.2], [0.3, -0.5]]), np.array([0.0, 0.1]), "tanh"),
            Layer(np.array([[1.0, 0.5]]), np.array([0.0]), "identity"),
        ]
    )
    plant = pv.Continuous({x: v, v: u - 0.1 * v}, inputs=[u], period=0.1, step=0.02)
    loop = pv.ClosedLoop(plant, stages=[pv.Stage(net, inputs=[x, v], output="u")])
    res = pv.verify(loop, init={"x": (0.9, 1.1), "v": (-0.1, 0.1)}, steps=30, safe=[x <= 1.5, x >= -1.5], progress=False)
    assert res.verdict == "verified"
    assert_contains_simulations(loop, res, n=300)
    final = np.asarray(res.cells[0].boxes[-1])
    assert final[0, 1] - final[0, 0] < 0.2  # not vacuous: the sampled spread is about 0.12
    # Safety is checked along the flow, not only at the sampling instants.
    tight = pv.verify(loop, init={"x": (0.9, 1.1), "v": (-0.1, 0.1)}, steps=30, safe=x <= 1.1, progress=False)
    assert tight.verdict != "verified"


def test_the_bar_shows_the_step_a_running_cell_reached():
    """A running cell raises its engine counter to its deepest step as it goes; the bar shows
    the counters of the running cells (deepest first), so a long cell shows progress."""
    from percver import _core
    from percver.verification.campaign import Progress, run_cells

    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: 0.9 * x}))
    problem = loop.compile(safe=[(x - 5, "<=", "x <= 5", None)], goal=None, within=False, steps=30)
    counter, outcomes = _core.StepCounter(), []
    run_cells(problem, [[(0.0, 1.0)]], lambda i, o, rss: outcomes.append(o), {}, 1, counter)
    assert outcomes[0].verdict == "verified" and counter.get() == outcomes[0].deepest_step == 30
    bar = Progress(threading.RLock())
    bar.start(2)
    try:
        idle = _core.StepCounter()
        bar.cell_started(counter, 30)
        other = threading.Thread(target=bar.cell_started, args=(idle, 30))
        other.start()
        other.join()
        bar.settled("verified")
        assert "steps=30/30 0/30" in bar.tqdm.postfix
        bar.cell_ended()
        bar.settled("verified")
        assert "steps=0/30" in bar.tqdm.postfix
    finally:
        bar.close()


# Written by percver before cell outcomes crossed the Rust boundary as typed objects (they were
# dicts); the seconds are marked (1.5, 2.5) so that a resumed cell is told from a rerun one.
OLD_JOURNAL = """{"fingerprint": "bbf992233b11b913"}
{"box": {"x": [0.0, 0.5]}, "verdict": "verified", "seconds": 1.5, "nn_seconds": 0.0, "branches": 0, "steps_done": 3, "reason": null, "counterexample": null, "boxes": [[[0.0, 0.5]], [[-2.9420910152566677e-16, 0.4500000000000004]], [[-3.463895836830493e-16, 0.40500000000000047]], [[-4.09339229179296e-16, 0.36450000000000055]]], "peak_rss_mb": 77.4140625, "split": null, "deepest_step": 3}
{"box": {"x": [0.5, 1.0]}, "verdict": "verified", "seconds": 2.5, "nn_seconds": 0.0, "branches": 0, "steps_done": 3, "reason": null, "counterexample": null, "boxes": [[[0.5, 1.0]], [[0.4499999999999995, 0.9000000000000007]], [[0.4049999999999994, 0.8100000000000008]], [[0.36449999999999927, 0.729000000000001]]], "peak_rss_mb": 77.5390625, "split": null, "deepest_step": 3}
"""


def test_a_journal_written_with_dict_outcomes_resumes_and_new_lines_keep_its_fields(tmp_path):
    x = pv.variables("x")
    loop = pv.ClosedLoop(pv.Discrete({x: 0.9 * x}))
    kwargs = dict(init={"x": (0.0, 1.0)}, steps=3, safe=x <= 5, split={"x": 2}, progress=False, workers=1)
    old = tmp_path / "old.jsonl"
    old.write_text(OLD_JOURNAL)
    resumed = pv.verify(loop, journal=str(old), **kwargs)
    assert sorted(c.seconds for c in resumed.cells) == [1.5, 2.5]  # read back, not run again
    new = tmp_path / "new.jsonl"
    fresh = pv.verify(loop, journal=str(new), **kwargs)
    assert [c.verdict for c in fresh.cells] == [c.verdict for c in resumed.cells] == ["verified", "verified"]
    old_lines, new_lines = ([json.loads(line) for line in p.read_text().splitlines()] for p in (old, new))
    assert new_lines[0] == old_lines[0]  # the same problem's fingerprint
    # New lines keep every old field, in order (the splitter's decisions, "options" and "into", come after).
    assert [list(line)[: len(o)] for line, o in zip(new_lines[1:], old_lines[1:])] == [list(o) for o in old_lines[1:]]
    for line in new_lines[1:]:
        assert len(line["boxes"]) == line["steps_done"] + 1 and line["peak_rss_mb"] > 0


def test_cell_outcomes_are_typed_picklable_and_checked():
    import pickle

    from percver import _core

    x = pv.variables("x")
    problem = pv.ClosedLoop(pv.Discrete({x: 0.5 * x})).compile(safe=[(x - 5, "<=", "x <= 5", None)], goal=None, within=False, steps=2)
    outcomes = []
    _core.verify_cells(problem, [[(0.0, 1.0)]], lambda i, o: outcomes.append(o))
    (outcome,) = outcomes
    assert isinstance(outcome, _core.CellOutcome)
    assert (outcome.verdict, outcome.reason, outcome.steps_done, outcome.deepest_step, outcome.split) == ("verified", None, 2, 2, None)
    assert len(outcome.boxes) == 3 and outcome.boxes[0] == [(0.0, 1.0)]
    lo, hi = outcome.boxes[2][0]
    assert lo <= 0.0 and 0.25 <= hi < 0.25 + 1e-9  # 0.5^2 of [0, 1], outward rounded
    again = pickle.loads(pickle.dumps(outcome))
    assert (again.verdict, again.boxes, again.seconds, again.branches) == (
        outcome.verdict,
        outcome.boxes,
        outcome.seconds,
        outcome.branches,
    )
    with pytest.raises(pv.InputError, match="'verified', 'unknown' or 'violated', not 'maybe'"):
        _core.CellOutcome("maybe", None, 0, 0, [], 0.0, 0.0, 0, 0, None)
