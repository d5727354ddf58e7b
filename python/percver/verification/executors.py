"""Cells on other processes and machines: ``pv.verify(..., executor=...)``.

One path for every executor: a ``dask.distributed.Client`` (LocalCluster, SSH, dask-jobqueue) is
used through its ``concurrent.futures`` view, so a ProcessPoolExecutor or mpi4py's
MPIPoolExecutor runs exactly the same code; a scheduler address ``"tcp://host:8786"`` connects a
Client first.

The problem (plant, networks, property) is pickled once on the client and reaches each worker
process about once: a task carries the problem's key (a hash of its pickle) and a batch of cells;
a worker that does not hold that problem yet answers MISSING and the batch goes again with the
problem, which the worker compiles and keeps. So a worker restarted after a crash gets the
problem with its first batch, without set-up hooks (Dask plugins, pool initializers) that only
some executors have. Workers do all of a cell's work (probe, engine, random runs); the client
only draws cells, journals outcomes as each batch completes, and queues sub-cells, so one client
keeps many workers busy. Random runs follow the campaign's rule: the cells the splitter settles
unknown go back to the workers in a batch of their own (:func:`sample_batch`), the ones it cuts
are not sampled. A batch whose task fails (its worker died) is sent again; its cells were not
journaled, and each drawn cell is in exactly one batch in flight, so none is lost or counted
twice.
"""

from __future__ import annotations

import concurrent.futures as cf
import copyreg
import hashlib
import io
import os
import pickle
import time
from collections import OrderedDict
from typing import Optional

from percver.errors import InputError, MissingDependencyError, PercverError
from percver.networks import Network
from percver.verification.campaign import run_cells, until
from percver.verification.falsify import falsify

MISSING = "percver: the problem is not on this worker yet"
RETRIES = 3  # resubmissions of a batch whose task failed (e.g. its worker died)
TASK_SECONDS = 0.25  # batches are sized to run about this long: overhead per task stays small
# Cells per batch at least while enough remain: a worker probes a batch's cells in one float
# simulation, whose cost is mostly per step, not per run (Mountain Car's blur loop, measured:
# 16 cells' probes cost 4 times 1 cell's, which is a tenth of the cell's engine run).
PROBE_CELLS = 8
MAX_BATCH = 512
_PROBLEMS: OrderedDict = OrderedDict()  # in each worker process: key -> (compiled problem, loop, property)
_KEPT = 4


class ExecutorError(PercverError):
    """The executor broke, or a batch of cells kept failing on it; finished cells are journaled."""


def _network(layers, scale, offset, name, input_names):
    return Network(layers, scale=scale, offset=offset, name=name, input_names=input_names)


def _reduce_network(net: Network):
    # By its arrays: the compiled Rust twin a Network may cache is rebuilt on the worker.
    return _network, (net.layers, net.scale, net.offset, net.name, net.input_names)


def _held(key: str, payload: Optional[bytes]):
    """On a worker: the problem ``key`` as (compiled problem, loop, property), loaded from
    ``payload`` if it is not held yet; None when it is not held and no payload came."""
    held = _PROBLEMS.get(key)
    if held is None:
        if payload is None:
            return None
        try:
            loop, prop, safe, goal, within, steps = pickle.loads(payload)
        except (AttributeError, ImportError) as error:
            raise ExecutorError(
                f"a worker cannot load the problem ({error}): classes and functions the loop uses must be importable "
                "on the workers (define them in a module installed there, not in __main__ or a notebook)"
            ) from None
        held = _PROBLEMS[key] = (loop.compile(safe=safe, goal=goal, within=within, steps=steps), loop, prop)
        while len(_PROBLEMS) > _KEPT:
            _PROBLEMS.popitem(last=False)
    return held


def run_batch(key: str, payload: Optional[bytes], cells: list, options: dict, sampling: tuple):
    """On a worker: per cell (a :class:`~percver.Box`) what the local pool does with it, or
    MISSING. A cell whose probe (centre and corners) violates the property gives
    ``{"probe": counterexample}`` without an engine run; the others run the engine (``options``,
    the same for the batch) and give ``{"outcome": CellOutcome, "rss": peak MB, "counterexample":
    ...}``, those it says "violated" simulated from ``sampling`` = (random runs per cell, seed)
    points (the others' runs wait for the splitter: :func:`sample_batch`). The runs depend only
    on the cell and the seed, so verdicts and counterexamples equal a local run's."""
    held = _held(key, payload)
    if held is None:
        return MISSING
    problem, loop, prop = held
    out = [{"probe": cex} if cex is not None else None for cex in falsify(loop, prop, cells, prop.steps, 0, sampling[1])]
    engine = [k for k, o in enumerate(out) if o is None]
    options = dict(options)
    deadline = options.pop("deadline", None)
    # Under a time limit each cell gets the time left when it starts (the worker's clock against
    # the driver's, which NTP keeps close), not the batch's when it was sent.
    for group in [engine] if deadline is None else [[k] for k in engine]:

        def done(i, outcome, rss, group=group):
            out[group[i]] = {"outcome": outcome, "rss": rss, "counterexample": None}

        given = options if deadline is None else until(options, deadline - time.time())
        run_cells(problem, [cells[k].bounds for k in group], done, given, workers=1)
    violated = [k for k in engine if out[k]["outcome"].verdict == "violated"]
    for k, cex in zip(violated, _sample(loop, prop, [cells[k] for k in violated], sampling)):
        out[k]["counterexample"] = cex
    return out


def sample_batch(key: str, payload: Optional[bytes], cells: list, sampling: tuple):
    """On a worker: per cell the splitter settled unknown, the first violation among its random
    runs (or None), as :meth:`Campaign.sample <percver.verification.campaign.Campaign.sample>`
    finds it locally; or MISSING."""
    held = _held(key, payload)
    if held is None:
        return MISSING
    _, loop, prop = held
    return _sample(loop, prop, cells, sampling)


def _sample(loop, prop, cells: list, sampling: tuple) -> list:
    samples, seed = sampling
    return falsify(loop, prop, cells, prop.steps, samples, seed, probe=False) if samples > 0 and cells else [None] * len(cells)


def dumps(problem) -> bytes:
    """``problem`` pickled, networks by their arrays; a part that cannot be pickled is named."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = {**copyreg.dispatch_table, Network: _reduce_network}
    try:
        pickler.dump(problem)
    except (pickle.PicklingError, TypeError, AttributeError) as error:
        raise ExecutorError(
            f"the loop cannot be sent to the executor's workers: {error}. Build it from percver's parts (expressions, "
            "pv.Network, stages) and module-level classes, without lambdas, open files or locks, or verify without executor="
        ) from None
    return buffer.getvalue()


def _is_dask_client(obj) -> bool:
    return type(obj).__module__.startswith("distributed") and hasattr(obj, "get_executor")


class Runner:
    """Feeds the cells of all parts of a call to an executor in batches, a bounded number in flight
    (a row of 10^4 cells never sits in the scheduler at once), and settles each batch's outcomes
    into its part's journal as it completes."""

    def __init__(self, executor, problem: tuple, slots: Optional[int] = None, batch: Optional[int] = None):
        """``problem`` = (loop, property, safe, goal, within, steps), pickled here: before any work."""
        self.client = None
        if slots is not None and slots < 1:
            raise InputError(f"workers must be at least 1, got {slots}")
        if batch is not None and batch < 1:
            raise InputError(f"batch must be at least 1 cell, got {batch}")
        self.slots, self.batch = slots, batch
        self.payload = dumps(problem)
        # Workers keep compiled problems by this key: all parts of a call share one.
        self.key = hashlib.sha256(self.payload).hexdigest()[:16]
        if isinstance(executor, str):
            try:
                from distributed import Client
            except ImportError:
                raise MissingDependencyError("executor='tcp://...' needs dask.distributed: pip install 'percver[dist]'") from None
            try:
                executor = self.client = Client(executor, timeout="20s")
            except (OSError, TimeoutError) as error:
                raise InputError(f"could not connect to a Dask scheduler at '{executor}': {error}") from None
        if _is_dask_client(executor):
            if executor.status in ("closing", "closed"):
                raise ExecutorError(f"the Dask client is {executor.status}: connect a new one (distributed.Client(cluster)) and rerun")
            # Asked again (1 ms) as batches go out: an adaptive cluster (dask-jobqueue) grows and shrinks.
            self.capacity = lambda: max(1, executor.scheduler_info(n_workers=0).get("total_threads", 1))
            # pure=False: a batch sent again after a failure must run again, not reuse the failure.
            self.pool = executor.get_executor(pure=False)
        elif isinstance(executor, cf.Executor):
            n = getattr(executor, "_max_workers", None) or getattr(executor, "num_workers", None) or os.cpu_count() or 1
            self.capacity = lambda: n
            self.pool = executor
        else:
            raise InputError(
                f"executor must be a dask.distributed.Client, a scheduler address 'tcp://host:8786' or a "
                f"concurrent.futures.Executor, got {type(executor).__name__}"
            )

    def close(self):
        if self.client is not None:
            self.client.close()

    def _batch_size(self, campaign, remaining: int, capacity: int) -> int:
        if self.batch:
            return self.batch
        if campaign.window is not None:  # a batch of several would hold cells the next draws must learn from
            return 1
        seconds, cells = campaign.cell_seconds
        by_time = TASK_SECONDS * cells / seconds if cells and seconds > 0 else 1
        # Near the end, smaller batches keep every worker busy.
        by_share = remaining // (2 * capacity)
        return int(max(1, min(max(by_time, PROBE_CELLS), by_share, MAX_BATCH)))

    def run(self, jobs: list):
        """Runs every cell of ``jobs`` (campaign, engine options): batches come from the first part
        that has cells, so the next part's cells fill the workers while a part's last ones run."""
        # future -> (campaign, options, cells, tries, settled); each drawn cell is in one. A batch
        # with ``settled`` (the cells' Cells, settled unknown) samples them; else it runs them.
        inflight: dict = {}

        def submit(campaign, options, cells, payload, tries, settled=None):
            sampling = (campaign.falsify, campaign.seed)
            try:
                if settled is None:
                    future = self.pool.submit(run_batch, self.key, payload, cells, options, sampling)
                else:
                    future = self.pool.submit(sample_batch, self.key, payload, cells, sampling)
            except Exception as error:  # BrokenProcessPool, a pool shut down, a Dask client closed (its cluster died)
                raise ExecutorError(
                    f"the executor cannot take work ({error}); finished cells are in the journal: rerun with a working executor to resume"
                ) from error
            inflight[future] = (campaign, options, cells, tries, settled)

        def fill():
            capacity = self.capacity()
            remaining = sum(campaign.remaining() for campaign, _ in jobs)
            # Two batches per worker by default: the next one is queued while one runs.
            while len(inflight) < (self.slots or 2 * capacity):
                for campaign, options in jobs:
                    drawn = campaign.draw(self._batch_size(campaign, remaining, capacity))
                    # One batch per set of engine settings the splitter chose (e.g. rebox).
                    groups: dict = {}
                    for cell, chosen in drawn:
                        groups.setdefault(tuple(sorted(chosen.items())), []).append(cell)
                    for chosen, cells in groups.items():
                        submit(campaign, campaign.batch_options({**options, **dict(chosen)}), cells, None, 0)
                    if drawn:
                        break
                else:
                    return

        def sample():
            for campaign, options in jobs:
                unsampled = campaign.unsampled()
                if unsampled:
                    submit(campaign, options, [cell for cell, _ in unsampled], None, 0, [c for _, c in unsampled])

        for campaign, _ in jobs:
            campaign.run_on(self.slots or 2 * self.capacity())
        try:
            while True:
                fill()
                sample()
                if not inflight:
                    return
                done, _ = cf.wait(inflight, return_when=cf.FIRST_COMPLETED)
                for future in done:
                    campaign, options, cells, tries, settled = inflight.pop(future)
                    try:
                        outcomes = future.result()
                    except PercverError:
                        raise
                    except Exception as error:  # the worker died or the task was lost
                        if tries >= RETRIES:
                            raise ExecutorError(
                                f"a batch of {len(cells)} cells failed {tries + 1} times on the executor "
                                f"(last: {error!r}); finished cells are in the journal: rerun with a working executor to resume"
                            ) from error
                        submit(campaign, options, cells, self.payload, tries + 1, settled)
                        continue
                    if isinstance(outcomes, str):  # MISSING
                        submit(campaign, options, cells, self.payload, tries, settled)
                        continue
                    if settled is not None:
                        for cell, c, cex in zip(cells, settled, outcomes):
                            campaign.sampled(cell, c, cex)
                        continue
                    for cell, outcome in zip(cells, outcomes):
                        campaign.settle(cell, outcome)
        finally:
            for future in inflight:
                future.cancel()
