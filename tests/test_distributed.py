"""Cells on executors (process pools, a real Dask LocalCluster), worker loss, timeouts, the
journal's cut last line, and the client's memory over 10,000 cells."""

import json
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
import tracemalloc
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver import _core
from percver.verification.executors import MISSING, ExecutorError, dumps, run_batch
from percver.networks import Layer, Network
from percver.verification import JournalWarning
from percver.verification.property import Property
from test_verify import mountain_car

MC = dict(init={"p": (-0.55, -0.45), "v": (0, 0)}, steps=150, within=True, progress=False)


def pool(workers):
    # Spawned, not forked: earlier tests leave threads (Dask's event loop) that a fork would copy.
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))


def by_box(result):
    return sorted(result.cells, key=lambda c: sorted(c.box.items()))


def journal_records(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines()[1:] if line.strip()]


def tiny_loop():
    """A cheap loop for many cells: x+ = x + 0.1 v, v+ = v + 0.1 u, u from a 2-2-1 tanh network."""
    x, v = pv.variables("x v")
    u = pv.variables("u")
    net = Network(
        [
            Layer(np.array([[-0.8, -1.2], [0.3, -0.5]]), np.array([0.0, 0.1]), "tanh"),
            Layer(np.array([[1.0, 0.5]]), np.array([0.0]), "identity"),
        ]
    )
    return pv.ClosedLoop(pv.Discrete({x: x + 0.1 * v, v: v + 0.1 * u}, inputs=[u]), stages=[pv.Stage(net, inputs=[x, v], output="u")]), x


def test_expressions_pickle_as_dags_and_evaluate_the_same():
    p, v, u = pv.variables("p v u")
    v_next = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    e = (
        pv.where(p + v_next <= -1.2, -1.2, p + v_next)
        + pv.sqrt(pv.exp(v) + 1) ** 1.5
        - (-u) ** 3
        + pv.uncertain(0.1, 0.2) * pv.tanh(u) / (2 + pv.sigmoid(p))
        + pv.maximum(pv.atan(p), pv.abs_(v))
    )
    back = pickle.loads(pickle.dumps(e))
    assert back.structural_hash() == e.structural_hash()
    x = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    np.testing.assert_array_equal(_core.eval_float([back], ["p", "v", "u"], x), _core.eval_float([e], ["p", "v", "u"], x))
    box = [(-0.3, -0.2), (0.0, 0.01), (0.5, 0.6)]
    assert _core.eval_interval([back], ["p", "v", "u"], box) == _core.eval_interval([e], ["p", "v", "u"], box)
    # Shared subexpressions are pickled once: 2^60 paths, 60 nodes.
    deep = p
    for _ in range(60):
        deep = deep * deep + deep
    assert len(pickle.dumps(deep)) < 10_000
    assert pickle.loads(pickle.dumps(deep)).structural_hash() == deep.structural_hash()
    c = pickle.loads(pickle.dumps(p + 1 >= v))
    assert isinstance(c, pv.Condition) and c.op == ">=" and c.margin().structural_hash() == (p + 1 >= v).margin().structural_hash()


def test_process_pool_ships_the_problem_once_and_matches_rayon(tmp_path):
    loop, p, v = mountain_car()
    loop.stages[0].component._core()  # a network with its compiled twin cached still ships
    kwargs = dict(MC, goal=p >= 0.45, split={"p": 12})
    local = pv.verify(loop, **kwargs)
    journal = tmp_path / "pool.jsonl"
    with pool(2) as executor:
        remote = pv.verify(loop, executor=executor, journal=str(journal), **kwargs)
    assert [c.verdict for c in by_box(remote)] == [c.verdict for c in by_box(local)]
    records = journal_records(journal)
    assert len(records) == 12 and all(r["peak_rss_mb"] > 10 for r in records)

    # The protocol on one worker process: without the problem it answers MISSING; once given, it
    # keeps it, and later batches carry only the fingerprint.
    prop = Property(loop, None, None, p >= 0.45, True, 150)
    safe, goal = prop.rust()
    payload = dumps((loop, prop, safe, goal, True, 150))
    cells = [loop.initial_box({"p": (-0.5, -0.499), "v": (0, 0)})]
    options = {"order": 5, "method": "taylor", "timeout": None}
    with pool(1) as executor:
        assert executor.submit(run_batch, "fp", None, cells, options, (8, 0)).result() == MISSING
        first = executor.submit(run_batch, "fp", payload, cells, options, (8, 0)).result()
        again = executor.submit(run_batch, "fp", None, cells, options, (8, 0)).result()
    outcome, repeated = first[0]["outcome"], again[0]["outcome"]
    assert outcome.verdict == repeated.verdict == "verified" and first[0]["rss"] > 10
    assert outcome.boxes == repeated.boxes and len(outcome.boxes) == outcome.steps_done + 1


def test_an_executor_gives_the_adaptive_splitter_the_cells_of_a_local_run(tmp_path):
    """The adaptive splitter learns from each outcome within its window: on an executor, as many
    cells out as on local threads make the same cells, options and verdicts."""
    loop, p, v = mountain_car()
    kwargs = dict(MC, init={"p": (-0.5, -0.4), "v": (0, 0.01)}, goal=p >= 0.45)
    local = pv.verify(loop, workers=2, **kwargs)
    with pool(2) as executor:
        remote = pv.verify(loop, executor=executor, journal=str(tmp_path / "adaptive.jsonl"), **kwargs)

    def cells(result):
        return [(json.dumps(c.box, sort_keys=True), c.verdict, json.dumps(c.options, sort_keys=True)) for c in by_box(result)]

    assert local.verdict == "verified" and len(local.cells) >= 50
    assert cells(remote) == cells(local)


def cell_for_cell(results):
    """Per cell of all parts: its box, verdict, reason and counterexample (start and step)."""
    out = []
    for r in results:
        for c in r.cells:
            cex = None if c.counterexample is None else (c.counterexample.initial, c.counterexample.step)
            out.append((json.dumps(c.box, sort_keys=True), c.verdict, c.reason, cex))
    return sorted(out, key=lambda t: t[0])


def test_dask_worker_killed_mid_row_loses_nothing_counts_nothing_twice_and_resumes(tmp_path):
    """Three parts at once on a real LocalCluster (verified cells; cells falsified by their probe
    or only by random runs; cells bisected by refine), one worker SIGKILLed while cells run: the
    journals hold every cell once, the results equal the local run cell for cell, and a rerun on
    the journals runs nothing."""
    distributed = pytest.importorskip("distributed")
    loop, p, v = mountain_car()
    parts = [
        pv.Part({"p": (-0.55, -0.45), "v": (0, 0)}, split={"p": 60}),
        pv.Part({"p": (-0.62, -0.56), "v": (0, 0)}, split={"p": 30}),
        pv.Part({"p": (-0.58, -0.40), "v": (0, 0)}, split={"p": 6}, order=3),
    ]
    # Starts in two bands are unsafe. The wide one holds probe points of cells of the first and
    # third parts; the thin one lies inside the first part's cell [-0.5, -0.4983] and the third
    # part's [-0.505, -0.4975], away from their centres and corners and from those of the cells
    # halved into the latter, and both are at min_width (settled, not cut): only their random
    # runs can falsify them.
    wide = pv.all_of(p >= -0.4575, p <= -0.4475)
    thin = pv.all_of(p >= -0.4997, p <= -0.4994)
    band = pv.during(pv.any_of(wide, thin), steps=(0, 0))
    kwargs = dict(steps=150, goal=p >= 0.45, within=True, unsafe=band, refine=True, min_width={"p": 0.005}, progress=False)
    local = pv.verify_parts(loop, parts, **kwargs)
    verdicts = {c.verdict for r in local for c in r.cells}
    assert {"verified", "falsified"} <= verdicts, verdicts
    sampled = [c.box["p"] for r in local for c in r.cells if c.counterexample is not None and "the engine" in c.reason]
    assert any(lo <= -0.4997 and -0.4994 <= hi for lo, hi in sampled), "random runs falsify the thin band's cell"
    journaled = [replace(part, journal=str(tmp_path / f"part{k}.jsonl")) for k, part in enumerate(parts)]
    killed = {}
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster) as client,
    ):
        pids = list(client.run(os.getpid).values())

        def kill_when_started():
            deadline = time.time() + 120
            while time.time() < deadline and killed.get("lines") is None:
                # Complete lines after the header: the journal may be mid-line while it is read.
                lines = sum(max(0, Path(part.journal).read_text().count("\n") - 1) for part in journaled if Path(part.journal).exists())
                if lines >= 5:
                    os.kill(pids[0], signal.SIGKILL)
                    killed["lines"] = lines
                time.sleep(0.01)

        killer = threading.Thread(target=kill_when_started)
        killer.start()
        # The scheduler's address: verify connects (and closes) a Client of its own.
        remote = pv.verify_parts(loop, journaled, executor=cluster.scheduler_address, **kwargs)
        killer.join()
        assert pids[0] not in client.run(os.getpid).values()
        total = sum(len(r.cells) for r in local)
        assert 5 <= killed["lines"] < total, "the worker must die mid-row"
        for part, r in zip(journaled, remote):
            boxes = [json.dumps(rec["box"], sort_keys=True) for rec in journal_records(part.journal)]
            assert len(boxes) == len(set(boxes)) >= len(r.cells), "every attempt journaled exactly once"
        assert cell_for_cell(remote) == cell_for_cell(local)
        sizes = [Path(part.journal).stat().st_size for part in journaled]
        again = pv.verify_parts(loop, journaled, executor=client, **kwargs)
        assert [Path(part.journal).stat().st_size for part in journaled] == sizes, "a rerun takes every cell from the journals"
        assert cell_for_cell(again) == cell_for_cell(local)
        client.close()
        with pytest.raises(ExecutorError, match=r"client is closed: connect a new one"):
            pv.verify_parts(loop, parts, executor=client, **kwargs)


def test_a_cluster_dying_mid_campaign_stops_it_with_the_fix_and_the_journal_resumes(tmp_path):
    distributed = pytest.importorskip("distributed")
    loop, p, v = mountain_car()
    journal = tmp_path / "dead.jsonl"
    kwargs = dict(MC, goal=p >= 0.45, split={"p": 400}, journal=str(journal))
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    client = distributed.Client(cluster)

    def close_when_started():
        deadline = time.time() + 120
        # Complete lines only (each ends with its newline): the campaign may be writing the next one.
        while time.time() < deadline and not (journal.exists() and journal.read_text().count("\n") - 1 >= 3):
            time.sleep(0.01)
        cluster.close()

    closer = threading.Thread(target=close_when_started)
    closer.start()
    try:
        with pytest.raises(ExecutorError, match="rerun with a working executor to resume"):
            pv.verify(loop, executor=client, **kwargs)
    finally:
        closer.join()
        client.close()
    done = journal_records(journal)
    boxes = [tuple(r["box"]["p"]) for r in done]
    assert 3 <= len(boxes) == len(set(boxes)) < 400
    result = pv.verify(loop, **kwargs)  # resumed locally: the journaled cells are not run again
    records = journal_records(journal)
    assert records[: len(done)] == done and len({tuple(r["box"]["p"]) for r in records}) == len(records) == 400
    assert result.verdict == "verified" and len(result.cells) == 400


def test_a_loop_workers_cannot_get_is_refused_with_the_fix(tmp_path, monkeypatch):
    loop, p, v = mountain_car()
    net = loop.stages[0].component

    class Mine(Network):  # a local class pickles by reference, which no worker can follow
        pass

    mine = pv.ClosedLoop(loop.plant, [pv.Stage(Mine(net.layers), inputs=["p", "v"], output="u")])
    kwargs = dict(MC, goal=p >= 0.45, split={"p": 2}, journal=str(tmp_path / "never.jsonl"))
    with pool(1) as executor:
        with pytest.raises(ExecutorError, match="cannot be sent to the executor's workers.*or verify without executor="):
            pv.verify(mine, executor=executor, **kwargs)
    assert not (tmp_path / "never.jsonl").exists()

    # A class the client imports from a module the workers lack: the worker names the fix.
    (tmp_path / "user_networks.py").write_text("from percver.networks import Network\n\nclass Theirs(Network):\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import user_networks

    theirs = pv.ClosedLoop(loop.plant, [pv.Stage(user_networks.Theirs(net.layers), inputs=["p", "v"], output="u")])
    prop = Property(theirs, None, None, p >= 0.45, True, 150)
    payload = dumps((theirs, prop, *prop.rust(), True, 150))
    monkeypatch.delitem(sys.modules, "user_networks")
    sys.path.remove(str(tmp_path))
    cells = [theirs.initial_box({"p": (-0.5, -0.499), "v": (0, 0)})]
    with pytest.raises(ExecutorError, match="must be importable on the workers"):
        run_batch("theirs", payload, cells, {"order": 5}, (0, 0))


def test_timed_out_cells_are_split_to_min_width_then_unknown_with_the_reason():
    loop, p, v = mountain_car()
    res = pv.verify(
        loop,
        init={"p": (-0.53, -0.45), "v": (0, 0)},
        steps=150,
        goal=p >= 0.45,
        within=True,
        progress=False,
        timeout_per_cell=1e-9,
        min_width={"p": 0.011},
    )
    widths = sorted(c.box["p"][1] - c.box["p"][0] for c in res.cells)
    assert widths == pytest.approx([0.02] * 4)  # 0.08 -> 0.04 -> 0.02: halves of 0.02 would be under min_width
    assert all(c.verdict == "unknown" and c.reason.startswith("timeout") and "min_width" in c.reason for c in res.cells)
    # Without a timeout the same cells verify: the split came from the timeout, not from refine.
    assert (
        pv.verify(loop, init={"p": (-0.53, -0.45), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, progress=False).verdict
        == "verified"
    )


def test_cut_last_journal_line_is_reported_dropped_and_rerun(tmp_path):
    loop, p, v = mountain_car()
    journal = tmp_path / "run.jsonl"
    kwargs = dict(MC, goal=p >= 0.45, split={"p": 6}, journal=str(journal))
    first = pv.verify(loop, **kwargs)
    text = journal.read_bytes()
    journal.write_bytes(text[:-40])  # power loss in the middle of the last line
    with pytest.warns(JournalWarning, match="line 7 was cut"):
        again = pv.verify(loop, **kwargs)
    assert [c.verdict for c in by_box(again)] == [c.verdict for c in by_box(first)]
    boxes = [tuple(r["box"]["p"]) for r in journal_records(journal)]
    assert len(boxes) == len(set(boxes)) == 6
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(pv.verify(loop, **kwargs).cells) == 6


def test_client_memory_stays_flat_over_10000_cells(tmp_path):
    loop, x = tiny_loop()
    journal = tmp_path / "many.jsonl"
    tracemalloc.start()
    try:
        with pool(2) as executor:
            res = pv.verify(
                loop,
                init={"x": (-1, 1), "v": (0, 0.1)},
                steps=3,
                safe=x <= 2,
                split={"x": 10_000},
                journal=str(journal),
                progress=False,
                executor=executor,
            )
        retained, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert res.verdict == "verified" and len(res.cells) == 10_000
    size = journal.stat().st_size
    # What is held at the end is the result (about 3x the journal's text); what came and went on
    # top of it (cells waiting, trajectories, batches in flight) does not scale with the cells:
    # holding one simulation or one outcome per cell would add tens of MB here.
    assert retained < 4 * size, (retained, size)
    assert peak - retained < 8e6, (peak, retained)


def test_bad_executor_batch_and_split_are_refused_before_any_work(tmp_path):
    loop, p, v = mountain_car()
    kwargs = dict(MC, goal=p >= 0.45, journal=str(tmp_path / "never.jsonl"))
    with pytest.raises(pv.InputError, match="concurrent.futures.Executor, got int"):
        pv.verify(loop, executor=42, **kwargs)
    with pytest.raises(pv.InputError, match="batch must be at least 1"):
        with pool(1) as executor:
            pv.verify(loop, executor=executor, batch=0, **kwargs)
    with pytest.raises(pv.InputError, match=r"split names \['q'\]"):
        pv.verify(loop, split={"q": 3}, **kwargs)
    assert not (tmp_path / "never.jsonl").exists()
