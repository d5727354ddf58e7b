"""``pv.verify``: split the initial set into cells, probe each by simulation (its centre and
corners), verify the rest in parallel, sample the cells the engine could not verify for a
counterexample, refine what stays unknown, and journal every finished cell.

Verdicts per cell: "verified" (the engine proved the property for every state of the cell),
"falsified" (a simulated trajectory from the cell violates it; the counterexample replays),
"unknown" (neither; the reason says at which step and on which variable precision was lost).
"""

from __future__ import annotations

import copy
import inspect
import math
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, fields, replace
from types import SimpleNamespace
from typing import Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import InputError
from percver.expr import Condition
from percver.sets import BoxLike
from percver.systems import ClosedLoop
from percver.verification.campaign import Campaign, Progress, run_local
from percver.verification.domains import domain_checks, domain_exits, flag_exits, runs
from percver.verification.splitters import Adaptive, Bisection, Grid
from percver.verification.journal import Journal
from percver.verification.journal import fingerprint as fingerprint_of
from percver.verification.property import Property
from percver.verification.results import Result


DEFAULTS = _core.CellSettings()  # the engine's defaults (one source: Rust), shown in signatures


@dataclass(frozen=True)
class Part:
    """A region of the initial set verified with its own grid (``split``), Taylor ``order``,
    in-cell ``max_splits`` and ``journal``: see :func:`verify_parts`."""

    init: Optional[BoxLike] = None
    split: Optional[dict] = None
    order: int = DEFAULTS.order
    max_splits: int = DEFAULTS.max_splits
    journal: Optional[str] = None


def verify(
    loop: ClosedLoop,
    init: Optional[BoxLike] = None,
    *,
    steps: Optional[int] = None,
    goal: Optional[Condition] = None,
    safe: Union[Condition, Sequence[Condition], None] = None,
    unsafe: Union[Condition, Sequence[Condition], None] = None,
    within: bool = False,
    reward: Optional[dict] = None,
    split: Optional[dict] = None,
    refine: bool = False,
    min_width: Optional[dict] = None,
    splitter=None,
    method: str = "taylor",
    order: int = DEFAULTS.order,
    max_splits: int = DEFAULTS.max_splits,
    rebox: bool = False,
    state_symbols: bool = False,
    workers: Optional[int] = None,
    executor=None,
    batch: Optional[int] = None,
    journal: Optional[str] = None,
    timeout_per_cell: Optional[float] = None,
    time_limit: Optional[float] = None,
    falsify: int = 32,
    progress: bool = True,
    seed: int = 0,
    strict: bool = False,
    validated=None,
) -> Result:
    """Prove ``loop`` satisfies the property from every state of ``init`` (see module doc).

    ``safe`` (stay in, every step), ``unsafe`` (avoid, every step) and ``goal`` (reach at the
    last step, or at some step with ``within``) take a condition, a :class:`~percver.Box`, or
    :func:`~percver.all_of` / :func:`~percver.any_of` of them; a list is their intersection (for
    ``unsafe`` one set to avoid). :func:`~percver.during` limits a safe or unsafe set to a window
    of steps or times (docs/verify.md, "Properties").

    The cells come from a splitter (:mod:`percver.verification.splitters`): ``splitter=pv.Grid(...)``,
    ``pv.Bisection(...)`` or ``pv.Adaptive(...)``; ``split=`` alone is a grid, ``refine=True`` a
    bisection down to ``min_width``, and with none of them the adaptive default starts from the
    whole set and halves what stays unknown while halving helps (docs/verify.md, "Cells").

    Cells run on this machine's cores (``workers`` threads, one cell each at a time) or, with
    ``executor=``, on a ``dask.distributed.Client``, a scheduler address ``"tcp://host:8786"`` or
    any ``concurrent.futures.Executor`` (``workers`` then caps the batches in flight; ``batch``
    fixes the cells per task, else tasks are sized to about a quarter second). A cell still running
    after ``timeout_per_cell`` seconds stops at the next step and is bisected down to
    ``min_width`` (default 1/64 of the initial set per dimension), then reported unknown.
    ``time_limit`` bounds the whole call's wall seconds: past it no cell starts, running ones
    stop at their next step, and both are reported unknown with the limit as their reason (not
    journaled: with ``journal=``, a rerun with a larger limit resumes from the finished cells).

    Each cell's centre and corners are simulated before the engine runs it (a violation there
    saves the engine run); a cell the engine leaves unknown is simulated from ``falsify`` random
    points of it once the splitter settles it (a cell bisected is not: its halves are probed), so
    a falsified cell's counterexample can come from either.

    Inside a cell, a part whose enclosure degrades (or that reaches a ``within`` goal only in
    part) is split where its enclosure was last precise and continued from there, and a condition
    (``pv.where``, in a stage or a discrete plant, e.g. a wall that some runs hit at this step) that
    holds on part of the set forks into one part per side, up to ``max_splits`` splits and forks
    per cell (0: never; conditions then take the hull of both sides; the adaptive default gives
    cells far larger than those verified near them fewer, see :class:`~percver.Adaptive`); they
    count as branches. An
    unknown cell's reach boxes end at the last step every part reached (``Cell.steps_done``); its
    ``Cell.deepest_step`` is the deepest step a part reached, where it gave up. While cells run,
    the progress bar shows the step each has reached (``steps=18/40 3/40``). ``rebox=True`` restarts
    a part from its box whenever a remainder is most of a state's enclosure (for loops whose
    remainders feed back and grow, such as the F1/10 LiDAR loop; it loses the dependency on the
    initial state, so it can be looser elsewhere). ``validated`` (a ``Domain``, e.g.
    ``diagnosis.domain``; by default the plant's own when it comes from a diagnosis) makes
    ``Result.validity`` say whether every reach box stays where the model was validated, or the
    first step and state where one leaves. ``state_symbols=True`` (Taylor method) keeps the
    remainders of the states that feed back as error symbols from step to step (a continuous
    plant's flowpipe carries them as variables), so that an error the controller corrects cancels
    instead of adding its magnitude again (the wrapping effect of a stiff feedback: ARCH-COMP's
    TORA with its ReLU controller); it pays where the loop's Jacobian varies little over a cell,
    and is off by default because on Mountain Car's cells it does not (bench/README.md); the
    adaptive default retries cells whose enclosure wrapped with it, and keeps it where that pays.

    A network that records its input domain (:attr:`percver.Network.domain`, the range it was
    trained on) is checked against the initial set before the run and against every cell's reach
    boxes after it, on the inputs that are states: where they leave it, a
    :class:`~percver.verification.domains.DomainWarning` names the stage, input, step, box and
    domain, and ``Result.domain_exits`` lists them. ``strict=True`` raises
    :class:`~percver.errors.NetworkDomainError` instead (after the run, with the results as its
    ``results`` attribute).
    """
    options = dict(locals())  # the keywords above, the one list of them
    part = Part(**{k: options.pop(k) for k in PART_KEYWORDS})
    return _verify_parts(options.pop("loop"), [part], options)[0]


def verify_parts(loop: ClosedLoop, parts: Sequence[Part], **options) -> list:
    """:func:`verify` on several :class:`Part` s of an initial set (regions that need different
    cell widths or orders), one :class:`Result` per part, each with the whole call's wall time.

    Locally, all parts' cells share one pool of ``workers`` threads, each running one cell at a
    time and taking the next from the first part that has one: no core waits for the last cell
    of a batch or of a part (verifying the parts one after another left a core idle at each
    part's end). On an executor likewise: batches come from the first part that has cells.
    ``options`` are :func:`verify`'s keywords but a part's own (init, split, order, max_splits,
    journal), the same for every part."""
    unknown = sorted(set(options) - set(SHARED_KEYWORDS))
    if unknown:
        raise TypeError(f"verify_parts() got unexpected keyword arguments {unknown}; it takes {', '.join(SHARED_KEYWORDS)}")
    defaults = {k: p.default for k, p in inspect.signature(verify).parameters.items() if k in SHARED_KEYWORDS}
    return _verify_parts(loop, parts, {**defaults, **options})


def _verify_parts(loop, parts: Sequence[Part], keywords: dict) -> list:
    """The campaign of :func:`verify_parts`, with every shared keyword of :func:`verify` given."""
    o = SimpleNamespace(**keywords)
    started = time.time()
    if not isinstance(loop, ClosedLoop) and isinstance(getattr(loop, "loop", None), ClosedLoop):
        # A loaded problem (e.g. pv.load_verisig): its file's init, horizon and property fill what is not given.
        d = loop.defaults
        parts = [p if p.init is not None else replace(p, init=d["init"]) for p in parts]
        o.steps = d["steps"] if o.steps is None else o.steps
        if o.goal is None and o.safe is None and o.unsafe is None:
            o.goal, o.safe, o.within = d.get("goal"), d.get("safe"), d.get("within", o.within)
        loop = loop.loop
    if not isinstance(loop, ClosedLoop):
        raise InputError("verify() needs a pv.ClosedLoop")
    if not parts:
        raise InputError("verify_parts() needs at least one pv.Part")
    for k, p in enumerate(parts):
        if not isinstance(p, Part):
            raise InputError(f"part {k} is a {type(p).__name__}; give pv.Part(init=..., split=..., order=..., max_splits=..., journal=...)")
    if any(p.init is None for p in parts):
        raise InputError("verify() needs init={state: (lo, hi), ...}")
    if not (isinstance(o.steps, int) and o.steps >= 0):
        raise InputError(f"steps must be a non-negative integer, got {o.steps!r}")
    limit = o.time_limit
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, float)) or not 0 < limit < math.inf):
        raise InputError(f"time_limit must be a positive number of seconds, got {limit!r}")
    deadline = None if limit is None else time.monotonic() + limit
    if o.method not in ("taylor", "verisig"):
        raise InputError(f"unknown method '{o.method}'; use 'taylor' or 'verisig'")
    for p in parts:
        if not (isinstance(p.max_splits, int) and p.max_splits >= 0):
            raise InputError(f"max_splits must be a non-negative integer, got {p.max_splits!r}")
    from percver.validate.verifiable import validated_domain, validity

    validated, caveats = validated_domain(loop, o.validated)  # of the loop as given: the plants below are rebuilt
    if o.reward is not None:
        loop = loop.with_accumulators(o.reward)  # sums as extra states: see ClosedLoop.with_accumulators
    loop = loop.with_held_parameters()  # parameters held over a run as states: see ClosedLoop.with_held_parameters
    boxes = [loop.initial_box(p.init) for p in parts]
    splitters = []  # each part's splitter and its initial cells, checked before any journal is opened
    for p, box in zip(parts, boxes):
        part_splitter = _splitter_of(p, o.splitter, o.refine, o.min_width, bool(o.rebox), bool(o.state_symbols), o.method)
        splitters.append((part_splitter, part_splitter.initial(box)))
    checks = domain_checks(loop)
    initial_exits = domain_exits(checks, [np.array([box.bounds]) for box in boxes])
    flag_exits(initial_exits, o.strict)  # before the run: strict then costs nothing
    prop = Property(loop, o.safe, o.unsafe, o.goal, o.within, o.steps)
    safe_r, goal_r = prop.rust()
    problem = loop.compile(safe=safe_r, goal=goal_r, within=o.within, steps=o.steps)
    runner = None
    if o.executor is not None:
        from percver.verification.executors import Runner

        # Checked, pickled and connected before any work.
        runner = Runner(o.executor, (loop, prop, safe_r, goal_r, o.within, o.steps), slots=o.workers, batch=o.batch)
    jobs = []
    lock = threading.RLock()  # one for all parts: they share the progress bar
    bar = Progress(lock)
    try:
        with ExitStack() as journals:
            for p, box, (splitter, cells) in zip(parts, boxes, splitters):
                settings = {
                    "steps": o.steps,
                    "method": o.method,
                    "order": p.order,
                    "max_splits": p.max_splits,
                    "rebox": bool(o.rebox),
                    "timeout_per_cell": o.timeout_per_cell,
                    "within": o.within,
                }
                if o.state_symbols:  # only when on, so that journals written before the option still resume
                    settings["state_symbols"] = True
                options = {
                    "order": p.order,
                    "method": o.method,
                    "timeout": o.timeout_per_cell,
                    "max_splits": p.max_splits,
                    "rebox": bool(o.rebox),
                    "state_symbols": bool(o.state_symbols),
                }
                journal = Journal(p.journal, fingerprint_of(loop, prop, settings))
                journals.callback(journal.close)
                campaign = Campaign(
                    loop,
                    prop,
                    box,
                    splitter,
                    cells,
                    journal,
                    bar,
                    timeout=o.timeout_per_cell,
                    falsify=o.falsify,
                    seed=o.seed,
                    lock=lock,
                    deadline=None if deadline is None else (limit, deadline),
                )
                if limit is not None:  # after the fingerprint: a rerun with another limit resumes the journal
                    settings["time_limit"] = limit
                jobs.append((campaign, settings, options))
            if o.progress:
                bar.start(sum(campaign.left for campaign, *_ in jobs))
            try:
                if runner is None:
                    run_local([(campaign, problem, options) for campaign, _, options in jobs], o.workers, bar)
                else:
                    runner.run([(campaign, options) for campaign, _, options in jobs])
            finally:
                for campaign, _, _ in jobs:
                    campaign.flush()
                    campaign.expire()
    finally:
        if runner is not None:
            runner.close()
        bar.close()
    seconds = time.time() - started
    results = [
        Result(
            loop.states,
            box.to_dict(),
            campaign.cells,
            seconds,
            settings,
            domain_exits(checks, runs(campaign.cells, loop.states)),
            lost=campaign.lost,
        )
        for box, (campaign, settings, _) in zip(boxes, jobs)
    ]
    for result in results:
        _record_held(loop, result)
    flagged = {(e["stage"], e["input"]) for e in initial_exits}
    flag_exits([e for r in results for e in r.domain_exits if (e["stage"], e["input"]) not in flagged], o.strict, results)
    return validity(results, validated, caveats)


# The keywords a Part carries, and those verify shares with verify_parts: one list, verify's signature.
PART_KEYWORDS = tuple(f.name for f in fields(Part))
SHARED_KEYWORDS = tuple(k for k in inspect.signature(verify).parameters if k != "loop" and k not in PART_KEYWORDS)


def _record_held(loop: ClosedLoop, result) -> None:
    """Makes each counterexample a run of the loop as given: the parameters held over a run
    (states of the loop verified, see ``ClosedLoop.with_held_parameters``) leave its initial state
    and trajectory for its ``parameters``, so that ``loop.simulate(x0, steps,
    parameters=cex.parameter_values())`` replays it."""
    if not loop.held:
        return
    keep = [i for i, name in enumerate(loop.states) if name not in loop.held]
    for cell in result.cells:
        cex = cell.counterexample
        if cex is None or not set(loop.held) <= set(cex.initial):
            continue
        cex.parameters += [{"id": pid, "range": [lo, hi], "value": float(cex.initial[name])} for name, (pid, lo, hi) in loop.held.items()]
        cex.initial = {name: value for name, value in cex.initial.items() if name not in loop.held}
        cex.trajectory = [[row[i] for i in keep] for row in cex.trajectory]


def _splitter_of(part: Part, splitter, refine: bool, min_width: Optional[dict], rebox: bool, symbols: bool, method: str):
    """The part's own splitter (a fresh copy of ``splitter``: an adaptive one learns per part);
    without one, ``split``/``refine``/``min_width`` name a grid or a bisection, and with none of
    them the adaptive default applies. With ``rebox`` every cell is reboxed already: an adaptive
    splitter does not retry cells with it, nor with state symbols (given already, ignored by a
    reboxed cell, or by another method than Taylor models)."""
    if splitter is not None:
        if part.split or refine or min_width:
            raise InputError("give splitter= or split=/refine=/min_width=, not both (a splitter carries its own grid and widths)")
        if not all(hasattr(splitter, m) for m in ("initial", "prepare", "again", "learn")):
            raise InputError(f"splitter= takes pv.Grid, pv.Bisection, pv.Adaptive or an object with their methods, got {splitter!r}")
        chosen = copy.deepcopy(splitter)
    elif refine:
        return Bisection(part.split or {}, min_width or {})
    elif part.split or min_width:
        return Grid(part.split or {}, min_width or {})
    else:
        chosen = Adaptive()
    if isinstance(chosen, Adaptive):
        chosen.call_order = part.order
    if rebox and isinstance(chosen, Adaptive):
        chosen.rebox = False
    if (rebox or symbols or method != "taylor") and isinstance(chosen, Adaptive):
        chosen.symbols = False  # every cell runs so already, or the engine ignores them
    return chosen
