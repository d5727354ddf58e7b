"""A call's time limit (``time_limit=``): past it no cell starts and running cells stop at their next
step, reported unknown with the limit as their reason; the result still tiles the initial set, the
hints name a longer limit, and a rerun with the same journal resumes from the cells that finished."""

import json

import pytest

import percver as pv
from percver.errors import InputError

from closed_loops import mountain_car_images

INIT = {"p": (-0.5, -0.49), "v": (0.0, 0.0), "delta": (1.0, 1.2)}


@pytest.fixture(scope="module")
def loop():
    return mountain_car_images()


def _property():
    p = pv.variables("p")
    return dict(steps=150, goal=p >= 0.45, within=True, progress=False)


def _tiles(result) -> bool:
    """The cells' p widths add up to the initial set's (the grid splits p only)."""
    return sum(c.box["p"][1] - c.box["p"][0] for c in result.cells) == pytest.approx(INIT["p"][1] - INIT["p"][0])


def _journaled(path) -> list:
    return [json.loads(line) for line in path.read_text().splitlines()[1:]]


def test_cells_past_the_limit_are_unknown_and_a_rerun_resumes_from_the_journal(loop, tmp_path):
    # 40 cells of about a quarter second each cannot all run on 2 threads in one second.
    journal = tmp_path / "limited.jsonl"
    limited = pv.verify(loop, INIT, split={"p": 40}, workers=2, time_limit=1.0, journal=str(journal), **_property())
    assert limited.verdict == "unknown" and len(limited.cells) == 40 and _tiles(limited)
    unknown = [c for c in limited.cells if c.verdict == "unknown"]
    assert unknown and all(c.reason == "not run within time_limit=1 s" or c.reason.endswith("by time_limit=1 s") for c in unknown)
    assert any(c.reason.startswith("not run") for c in unknown)
    # Only the cells that finished are journaled; the limit is no part of the fingerprint.
    finished = _journaled(journal)
    assert len(finished) == 40 - len(unknown) and all(c["verdict"] == "verified" for c in finished)
    assert limited.settings["time_limit"] == 1.0
    (hint,) = [h for h in limited.hints(loop) if "time_limit" in h.keywords]
    assert hint.keywords == {"time_limit": 4.0} and hint.cells == len(unknown) and "journal=" in hint.why
    resumed = pv.verify(loop, INIT, split={"p": 40}, workers=2, journal=str(journal), **_property())
    assert resumed.verdict == "verified" and len(resumed.cells) == 40
    assert len(_journaled(journal)) == 40  # the finished cells were not run again


def test_a_running_cell_stops_at_the_limit_and_is_not_halved(loop, tmp_path):
    """The adaptive default's one cell (about 1.5 s here) is stopped, not halved as a lost cell
    would be; it is not journaled."""
    journal = tmp_path / "stopped.jsonl"
    result = pv.verify(loop, INIT, workers=2, time_limit=0.3, journal=str(journal), **_property())
    (cell,) = result.cells
    assert cell.verdict == "unknown" and cell.reason == f"stopped at step {cell.steps_done} by time_limit=0.3 s"
    assert 0 < cell.steps_done < 150 and all(tuple(cell.box[k]) == INIT[k] for k in INIT)
    assert _journaled(journal) == []


def test_dask_workers_stop_their_cells_at_the_limit(loop):
    """On a real LocalCluster each cell of a batch gets the time left when it starts there."""
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster) as client,
    ):
        result = pv.verify(loop, INIT, split={"p": 40}, executor=client, time_limit=1.0, **_property())
    assert result.verdict == "unknown" and len(result.cells) == 40 and _tiles(result)
    assert any("time_limit=1 s" in (c.reason or "") for c in result.cells)


@pytest.mark.parametrize("bad", [0, -1.0, float("inf"), float("nan"), "10", True])
def test_a_bad_time_limit_is_a_clear_error(loop, bad):
    with pytest.raises(InputError, match="time_limit must be a positive number of seconds"):
        pv.verify(loop, INIT, time_limit=bad, **_property())
