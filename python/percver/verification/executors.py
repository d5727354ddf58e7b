"""Cells on other processes and machines: ``pv.verify(..., executor=...)``.

One path for every executor: a ``dask.distributed.Client`` (LocalCluster, SSH, dask-jobqueue) is
used through its ``concurrent.futures`` view, so a ProcessPoolExecutor or mpi4py's
MPIPoolExecutor runs exactly the same code; a scheduler address ``"tcp://host:8786"`` connects a
Client first.

The problem (plant, networks, property) is pickled once on the client and reaches each worker
process about once: a task carries the problem's fingerprint and a batch of cells; a worker that
does not hold that problem yet answers MISSING and the batch goes again with the problem, which
the worker compiles and keeps. So a worker restarted after a crash gets the problem with its
first batch, without set-up hooks (Dask plugins, pool initializers) that only some executors have.
Outcomes come back per batch, in completion order, into the journal and the progress bar.
"""

from __future__ import annotations

import concurrent.futures as cf
import copyreg
import io
import os
import pickle
from collections import OrderedDict
from typing import Optional

from percver.errors import InputError, MissingDependencyError, PercverError
from percver.networks import Network
from percver.verification.campaign import run_cells

MISSING = "percver: the problem is not on this worker yet"
RETRIES = 3  # resubmissions of a batch whose task failed (e.g. its worker died)
TASK_SECONDS = 0.25  # batches are sized to run about this long: overhead per task stays small
MAX_BATCH = 512
_PROBLEMS: OrderedDict = OrderedDict()  # in each worker process: fingerprint -> compiled loop
_KEPT = 4


class ExecutorError(PercverError):
    """The executor broke, or a batch of cells kept failing on it; finished cells are journaled."""


def _network(layers, scale, offset, name, input_names):
    return Network(layers, scale=scale, offset=offset, name=name, input_names=input_names)


def _reduce_network(net: Network):
    # By its arrays: the compiled Rust twin a Network may cache is rebuilt on the worker.
    return _network, (net.layers, net.scale, net.offset, net.name, net.input_names)


def dumps(problem) -> bytes:
    """``problem`` pickled, networks by their arrays."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = {**copyreg.dispatch_table, Network: _reduce_network}
    pickler.dump(problem)
    return buffer.getvalue()


def run_batch(fingerprint: str, payload: Optional[bytes], cells: list, options: dict):
    """On a worker: (outcome, peak RSS in MB) of each of ``cells`` (lists of (lo, hi)), or MISSING."""
    problem = _PROBLEMS.get(fingerprint)
    if problem is None:
        if payload is None:
            return MISSING
        loop, safe, goal, within, steps = pickle.loads(payload)
        problem = loop.compile(safe=safe, goal=goal, within=within, steps=steps)
        _PROBLEMS[fingerprint] = problem
        while len(_PROBLEMS) > _KEPT:
            _PROBLEMS.popitem(last=False)
    out = [None] * len(cells)
    run_cells(problem, cells, lambda i, outcome, rss: out.__setitem__(i, (outcome, rss)), options, workers=1)
    return out


def _is_dask_client(obj) -> bool:
    return type(obj).__module__.startswith("distributed") and hasattr(obj, "get_executor")


class Runner:
    """Feeds a campaign's cells to an executor in batches, a bounded number in flight."""

    def __init__(self, executor, slots: Optional[int] = None, batch: Optional[int] = None):
        self.client = None
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
        if slots is not None and slots < 1:
            raise InputError(f"workers must be at least 1, got {slots}")
        if batch is not None and batch < 1:
            raise InputError(f"batch must be at least 1 cell, got {batch}")
        self.slots, self.batch = slots, batch

    def close(self):
        if self.client is not None:
            self.client.close()

    def _batch_size(self, campaign, capacity: int) -> int:
        if self.batch:
            return self.batch
        seconds, cells = campaign.cell_seconds
        by_time = TASK_SECONDS * cells / seconds if cells and seconds > 0 else 1
        # Near the end, smaller batches keep every worker busy.
        by_share = campaign.remaining() // (2 * capacity)
        return int(max(1, min(by_time, by_share, MAX_BATCH)))

    def run(self, campaign, problem: tuple, fingerprint: str, options: dict):
        """Runs every cell of ``campaign``; ``problem`` = (loop, safe, goal, within, steps)."""
        inflight: dict = {}
        payload = None

        def submit(cells, data, tries):
            try:
                future = self.pool.submit(
                    run_batch, fingerprint, data, [c.bounds for c in cells], {**options, **campaign.options_of(cells[0])}
                )
            except RuntimeError as error:  # BrokenProcessPool, or shut down
                raise ExecutorError(
                    f"the executor cannot take work ({error}); finished cells are in the journal: rerun with a working executor to resume"
                ) from error
            inflight[future] = (cells, tries)

        try:
            while True:
                capacity = self.capacity()
                # Two batches per worker by default: the next one is queued while one runs.
                while len(inflight) < (self.slots or 2 * capacity):
                    cells = campaign.take(self._batch_size(campaign, capacity))
                    if not cells:
                        break
                    submit(cells, None, 0)
                if not inflight:
                    return
                done, _ = cf.wait(inflight, return_when=cf.FIRST_COMPLETED)
                for future in done:
                    cells, tries = inflight.pop(future)
                    try:
                        outcomes = future.result()
                    except PercverError:
                        raise
                    except Exception as error:  # the worker died or the task was lost
                        if tries >= RETRIES:
                            raise ExecutorError(
                                f"a batch of {len(cells)} cells failed {tries + 1} times on the executor "
                                f"(last: {error!r}); finished cells are in the journal: rerun to resume"
                            ) from error
                        payload = payload or dumps(problem)
                        submit(cells, payload, tries + 1)
                        continue
                    if isinstance(outcomes, str):  # MISSING
                        payload = payload or dumps(problem)
                        submit(cells, payload, tries)
                        continue
                    for cell, (outcome, rss) in zip(cells, outcomes):
                        campaign.record(cell, outcome, rss)
        finally:
            for future in inflight:
                future.cancel()
