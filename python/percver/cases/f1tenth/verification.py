"""The F1/10 row of the paper's Table 1: the closed loop of the original verification model.

canonical 21-ray LiDAR (``world.scan_exprs``: which wall a ray hits is a ``where``)
-> normalised scan (r - 2.5) / 5 -> knock-out classifier c_n on (scan, pose features)
-> a ray whose probability is at or above its threshold reads 0.5 (max range), written as a
``where`` so that an undecided ray takes the hull of both readings -> denoiser h_d (x 0.5)
-> controller TD3_L21_64x64_C2 (x 15 degrees) -> bicycle model over 0.1 s, in the first
hallway's local coordinates (y1 to the left wall, y2 to the front wall, y3 speed, y4 heading).

Property of the original model (REFERENCE.md): start at rest 9 m from the front wall with y1
in [0.65, 0.85]; stay 0.15 m from every wall (y1 > 0.15, y2 > 0.15, and not both y1 and y2
at or beyond 1.35: the inner corner); get past the turn (y1 >= 2.5 with 0.15 <= y2 <= 1.35)
within ``STEPS`` control periods.

Two ways to run it (``mode``):
- ``"engine"``: ``pv.verify`` as is: each cell's state is one Taylor model carried over all
  steps. Measured here, it loses every cell between steps 25 and 35 (bench/README.md): the
  remainders of the state go around the feedback loop as intervals, so the stabilising
  feedback adds up instead of cancelling (about x2.3 per step whatever the cell width).
- ``"stepwise"`` (default): the same engine one control period at a time, each step started
  afresh from the box of the previous one (new Taylor-model variables for every state, so the
  whole step is symbolic and only the box wraps); a box the engine loses is bisected and both
  halves continue from that step; an undecided knock-out is split into its two cases
  (``knockout_cases``). Sound for the same reason as the engine: every step's box contains
  every state reachable from the previous box.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import data as f1data
from percver.cases.f1tenth import dynamics, noise, world
from percver.errors import InputError
from percver.sets import Box
from percver.verification.splitters import grid as cell_grid
from percver.verification.falsify import falsify as falsify_cells
from percver.verification.journal import Journal, cell_key, fingerprint
from percver.verification.property import Property, holds
from percver.verification.results import Cell, Result

MARGIN = 0.15
INNER = world.WIDTH - MARGIN
GOAL_Y1 = 2.5
STEPS = 50
INIT = {"y1": (0.65, 0.85), "y2": (9.0, 9.0), "y3": (0.0, 0.0), "y4": (0.0, 0.0)}
# The published campaign's cells: 5e-5 in y1 (REFERENCE.md).
PAPER_CELL = 5e-5
# Metres a ray moves per radian of heading at the range limit: how box sides in y4 compare
# with those in y1, y2 when a box is bisected.
LEVER = world.CONTROLLER_RANGE
# A step from a small box needs few terms: order 3 gave the verdicts of order 5 on the cells
# measured (bench/README.md) in 40% of the time; order 2 lost them.
STEPWISE_ORDER = 3
# Cases whose hull is at most this much larger than the largest of them go on as one part.
_MERGE = 1.25
# Box sides below this (m) never count as grown: a point start widens from nothing.
_NEGLIGIBLE = 1e-6
# Table 1 of the paper, F1/10 row.
PAPER_ROW = {"intervals": 8236, "avg_seconds": 10733.0, "avg_branches": 6.88}
PUBLISHED = ("RESULTS_SUMMARY.txt", "RESULTS_SUMMARY_0.75_0.85.txt")


def plant():
    """The bicycle model in hallway-local coordinates, steering ``u`` held over 0.1 s."""
    import percver as pv

    return pv.Continuous(dynamics.equations("local", delta="u"), inputs=["u"], period=dynamics.PERIOD)


def perception(controller, noise_model=None, denoiser=None, forced=None):
    """LiDAR -> [classifier, knock-out] -> [denoiser] -> controller, as a ``pv.Perception``.

    Without ``noise_model`` the controller reads the canonical scan (the loop without noise).
    ``forced={ray: knocked}`` fixes those rays' knock-out decisions (one case of a branch)."""
    import percver as pv
    from percver.expr import as_expr

    y1, y2, y4 = pv.variables("y1 y2 y4")
    scale = world.NORMALISATION_SCALE
    canonical = pv.Stage(
        world.scan_exprs(y1, y2, y4), inputs=[y1, y2, y4], output="scan", scale=scale, offset=-world.NORMALISATION_OFFSET * scale
    )
    noiser, reads = [], "scan"
    if noise_model is not None:
        pose = [0.1 * y1, 0.1 * (10.0 - y2), y4 / (1.5 * np.pi) + 1.0 / 3.0]
        noiser.append(pv.Stage(pose, inputs=[y1, y2, y4], output="pose"))
        noiser.append(pv.Stage(noise_model.network, inputs=["scan", "pose"], output="prob"))
        rays = range(noise_model.network.n_out)
        forced = forced or {}
        knocked = [
            pv.where(pv.Expr.var(f"prob_{i}") >= float(noise_model.thresholds[i]), float(noise_model.knocked[i]), pv.Expr.var(f"scan_{i}"))
            for i in rays
        ]
        for i, knock in forced.items():
            knocked[i] = as_expr(float(noise_model.knocked[i])) if knock else pv.Expr.var(f"scan_{i}")
        noiser.append(pv.Stage(knocked, inputs=["prob", "scan"], output="noised"))
        reads = "noised"
    clean = None
    if denoiser is not None:
        clean = pv.Stage(denoiser.network, inputs=[reads], output="clean", scale=noise.DENOISER_SCALE)
        reads = "clean"
    control = pv.Stage(controller.network, inputs=[reads], output="u", scale=float(dynamics.MAX_STEERING))
    return pv.Perception(canonical=canonical, noiser=noiser, denoiser=clean, controller=control)


def load_networks(networks="paper", controller: str = ctl.VERIFIED, data=None):
    """(controller, noise model, denoiser): the authors' 5x100 classifier and denoiser
    (``"paper"``), or those in a directory written by ``percver cases f1tenth train``
    (``"ours"`` = ``f1tenth_models``, or the directory itself)."""
    from percver.cases.f1tenth import study

    source = "f1tenth_models" if networks == "ours" else networks
    models, denoiser = study.load_models(source, sizes=["5x100"], data=data)
    if denoiser is None:
        raise InputError(f"'{source}' has no denoiser.onnx: the verified loop needs one (percver cases f1tenth train)")
    return ctl.load(controller, data), models["5x100"], denoiser


def closed_loop(networks="paper", *, noise_model: bool = True, controller: str = ctl.VERIFIED, data=None):
    """The verified loop; ``noise_model=False`` drops classifier and denoiser (canonical scan)."""
    import percver as pv

    if noise_model:
        control, classifier, denoiser = load_networks(networks, controller, data)
        chain = perception(control, classifier, denoiser)
    else:
        chain = perception(ctl.load(controller, data))
    return pv.ClosedLoop(plant(), chain)


def knockout_cases(control, classifier, denoiser, *, max_rays: int = 2, near: float = 0.05, samples: int = 64):
    """``cases`` for ``stepwise``: for a box, the rays whose knock-out probability comes within
    ``near`` of its threshold on float samples of the box (the ``max_rays`` closest), and one
    loop per combination of their decisions. Whatever the sampling misses stays a ``where``
    in every case, so the cases cover the step whichever rays they pick."""
    import itertools

    import percver as pv

    base = pv.ClosedLoop(plant(), perception(control, classifier, denoiser))
    upto = next(k for k, stage in enumerate(base.stages) if stage.output == "prob") + 1
    columns = base.signals["prob"]
    loops: dict = {}

    def cases(b) -> list:
        b = np.asarray(b, dtype=float)
        rng = np.random.default_rng(0)
        env = b[:, 0] + (b[:, 1] - b[:, 0]) * np.vstack([np.zeros(len(b)), np.ones(len(b)), rng.random((samples, len(b)))])
        for k in range(upto):
            env = np.concatenate([env, base.stage_float(k, env)], axis=1)
        margin = env[:, columns] - classifier.thresholds
        close = (margin.min(0) < near) & (margin.max(0) > -near)
        rays = sorted(np.flatnonzero(close), key=lambda i: np.abs(margin[:, i]).min())[:max_rays]
        out = []
        for decisions in itertools.product((False, True), repeat=len(rays)) if rays else ():
            key = tuple(zip(map(int, rays), decisions))
            if key not in loops:
                loops[key] = pv.ClosedLoop(plant(), perception(control, classifier, denoiser, forced=dict(key)))
            out.append(loops[key])
        return out

    return cases


def property_() -> dict:
    """``safe`` and ``goal`` of the original model (keyword arguments of ``pv.verify``)."""
    import percver as pv

    y1, y2 = pv.variables("y1 y2")
    return {
        "safe": [y1 > MARGIN, y2 > MARGIN, pv.maximum(INNER - y1, INNER - y2) > 0.0],
        "goal": [y1 >= GOAL_Y1, y2 >= MARGIN, y2 <= INNER],
        "within": True,
    }


def verify(
    y1=INIT["y1"],
    networks="paper",
    *,
    noise_model: bool = True,
    controller: str = ctl.VERIFIED,
    cell: float = PAPER_CELL,
    steps: int = STEPS,
    mode: str = "engine",
    sample: int | None = None,
    data=None,
    **verify_kwargs,
):
    """Verify the loop from y1 in ``y1`` (the other initial values and the property are the
    original model's), in cells of ``cell`` metres (the paper's 5e-5 by default); returns a
    ``pv.Result``. ``noise_model=False`` verifies the loop without classifier and denoiser.

    ``mode="engine"`` (the default) passes ``verify_kwargs`` to ``pv.verify``, with ``rebox=True``
    and ``max_splits=64`` unless given (undecided knock-outs fork, remainders do not feed back);
    ``mode="stepwise"`` (Python-driven, one period at a time from boxes) takes
    ``order``, ``method``, ``max_splits`` (box bisections per cell, default 16), ``workers``,
    ``journal``, ``falsify``, ``progress`` and ``seed``; with ``sample=N`` it runs only N cells
    spread evenly over the range (an estimate of coverage and time; the result's coverage is
    then that of the range, so use ``row(...)["verified"] / N``).
    """
    import percver as pv

    lo, hi = (float(v) for v in y1)
    if not lo <= hi:
        raise InputError(f"y1 range needs lo <= hi, got ({lo}, {hi})")
    if not cell > 0:
        raise InputError(f"cell width must be positive, got {cell}")
    if noise_model:
        control, classifier, denoiser = load_networks(networks, controller, data)
        loop = pv.ClosedLoop(plant(), perception(control, classifier, denoiser))
        if mode == "stepwise":
            verify_kwargs.setdefault("cases", knockout_cases(control, classifier, denoiser))
    else:
        loop = closed_loop(networks, noise_model=False, controller=controller, data=data)
    init = {**INIT, "y1": (lo, hi)}
    if mode == "engine":
        if sample is not None:
            raise InputError("sample= runs with mode='stepwise'; for the engine see bench/f1tenth_engine.py")
        verify_kwargs.setdefault("rebox", True)
        verify_kwargs.setdefault("max_splits", 64)
        return pv.verify(loop, init, steps=steps, split={"y1": cell}, **property_(), **verify_kwargs)
    if mode == "stepwise":
        verify_kwargs.setdefault("scale", {"y4": LEVER})
        verify_kwargs.setdefault("order", STEPWISE_ORDER)
        if sample is not None:
            n = max(1, int(round((hi - lo) / cell)))
            starts = lo + cell * np.unique(np.linspace(0, n - 1, min(sample, n)).round())
            verify_kwargs["cells"] = [{**init, "y1": (float(a), float(min(a + cell, hi)))} for a in starts]
        return stepwise(loop, init, steps=steps, split={"y1": cell}, **property_(), **verify_kwargs)
    raise InputError(f"unknown mode '{mode}': use 'stepwise' or 'engine'")


def stepwise(
    loop,
    init,
    *,
    steps: int,
    split: dict,
    safe=None,
    goal=None,
    within: bool = True,
    order: int = 5,
    method: str = "taylor",
    max_splits: int = 16,
    step_splits: int = 0,
    scale=None,
    growth: float = 3.0,
    cases=None,
    workers=None,
    journal=None,
    falsify: int = 32,
    progress: bool = True,
    seed: int = 0,
    chunk: int = 64,
    cells=None,
):
    """``pv.verify``'s cells run one control period at a time from boxes (see the module doc).

    All live boxes of all cells advance together, one ``verify_cells`` batch per step. A cell is
    verified when each of its boxes satisfies the goal at some step with safety proved up to
    there; falsified when a simulation from the cell violates the property (checked first);
    otherwise unknown, with the step and reason of the box that could not be continued.

    A step is lost when the engine cannot prove it or when it makes the box's widest side
    (in ``scale`` units per state, default 1) more than ``growth`` times longer: an undecided
    ``where`` took the hull of both branches. A lost box is first run once per case of
    ``cases(box)`` (closed loops over the same states whose steps together cover the step, e.g.
    one per decision of an undecided knock-out; each case's next box goes on as a part of its own,
    as Verisig's branches do, unless their hull is hardly larger), then bisected along its
    widest side, at most ``max_splits`` times per cell. Within a step the engine may split the
    step's domain ``step_splits`` times. Cases and bisections count as branches. Cells go in
    chunks of ``chunk`` (falsified, then run, then journaled) so that a long campaign journals
    as it goes. ``cells`` (initial sets) replaces the grid of ``init`` split by ``split``.
    """
    from percver import _core
    from percver.expr import bounds as expr_bounds

    box = loop.initial_box(init)
    prop = Property(loop, safe, None, goal, within, steps)
    if prop.goal is None:
        raise InputError("stepwise verification needs a goal (the box of a part that reached it stops)")
    safe_r, _ = prop.rust()
    plain = loop.compile(safe=safe_r, goal=None, within=False, steps=1)
    settings = {
        "steps": steps,
        "method": method,
        "order": order,
        "max_splits": max_splits,
        "within": within,
        "mode": "stepwise",
        "step_splits": step_splits,
        "growth": growth,
        "cases": cases is not None,
    }
    journal_ = Journal(journal, fingerprint(loop, prop, settings))
    names, margin, op = loop.states, prop.goal.margin(), prop.goal.op
    weights = np.array([float((scale or {}).get(n, 1.0)) for n in names])
    started = time.time()
    if cells is None:
        grid, count = cell_grid(box, split)
        cells = list(grid)
    else:
        cells = [loop.initial_box(c) for c in cells]
        count = len(cells)
    done = {k: journal_.done[key] for k, c in enumerate(cells) if (key := cell_key(c.to_dict())) in journal_.done}
    fresh = [k for k in range(len(cells)) if k not in done]
    live: dict = {}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=count, initial=len(done), unit="cell", desc="verify (stepwise)")

    def run(problems_boxes):
        """Outcomes of one step from each (problem, box), batched per problem."""
        outcomes = [None] * len(problems_boxes)
        groups: dict = {}
        for i, (problem, b) in enumerate(problems_boxes):
            groups.setdefault(id(problem), (problem, []))[1].append(i)
        for problem, index in groups.values():

            def collect(j, outcome, index=index):
                outcomes[index[j]] = outcome
                return True

            _core.verify_cells(
                problem,
                [list(map(tuple, problems_boxes[i][1])) for i in index],
                collect,
                _core.CellSettings(order=order, method=method, max_splits=step_splits),
                workers=workers,
            )
        return outcomes

    problems_of: dict = {}

    def compiled(case):
        if id(case) not in problems_of:
            problems_of[id(case)] = (case, case.compile(safe=safe_r, goal=None, within=False, steps=1))
        return problems_of[id(case)][1]

    def size(b):
        return ((b[:, 1] - b[:, 0]) * weights).max()

    def next_box(b, outs, rec):
        """The hull of the outcomes' step-1 boxes if all are proved and not grown, else None
        (their time is the cell's either way)."""
        for out in outs:
            rec["seconds"] += out.seconds
            rec["nn"] += out.nn_seconds
        if any(out.verdict != "verified" for out in outs):
            return None
        ends = np.array([out.boxes[1] for out in outs])
        nxt = np.column_stack([ends[:, :, 0].min(0), ends[:, :, 1].max(0)])
        return None if size(nxt) > growth * max(size(b), _NEGLIGIBLE) else nxt

    def record(k, step, nxt):
        boxes = live[k]["boxes"]
        if len(boxes) <= step:
            boxes.append(nxt)
        else:
            boxes[step] = np.column_stack([np.minimum(boxes[step][:, 0], nxt[:, 0]), np.maximum(boxes[step][:, 1], nxt[:, 1])])

    def finish(k, verdict, reason=None):
        rec = live.pop(k)
        boxes = [b.tolist() for b in rec["boxes"]]
        done[k] = Cell(cells[k].to_dict(), verdict, rec["seconds"], rec["nn"], rec["splits"], len(boxes) - 1, reason, None, boxes)
        journal_.write(done[k])
        if bar is not None:
            bar.update(1)

    try:
        for at in range(0, len(fresh), chunk):
            batch = fresh[at : at + chunk]
            found = falsify_cells(loop, prop, [cells[k] for k in batch], steps, falsify, seed) if falsify else [None] * len(batch)
            for k, cex in zip(batch, found):
                if cex is None:
                    live[k] = {"seconds": 0.0, "nn": 0.0, "splits": 0, "boxes": [np.array(cells[k].bounds)]}
                    continue
                done[k] = Cell(
                    cells[k].to_dict(), "falsified", counterexample=cex, reason=f"simulation violates {cex.violated} at step {cex.step}"
                )
                journal_.write(done[k])
                if bar is not None:
                    bar.update(1)
            pieces = [(k, 0, np.array(cells[k].bounds)) for k in batch if k in live]
            while pieces:
                ready = []
                for k, step, b in pieces:
                    if k not in live:
                        continue
                    if holds(op, np.array(expr_bounds(margin, Box(tuple(names), tuple(map(tuple, b))), method="interval"))).all():
                        continue  # this part has arrived
                    if step == steps:
                        finish(k, "unknown", f"step {step}: goal {prop.goal} not reached by the whole box")
                        continue
                    ready.append((k, step, b))
                first = run([(plain, b) for _, _, b in ready])
                lost = []
                pieces = []
                for (k, step, b), out in zip(ready, first):
                    if k not in live:
                        continue
                    nxt = next_box(b, [out], live[k])
                    if nxt is None:
                        lost.append((k, step, b, out))
                    else:
                        record(k, step + 1, nxt)
                        pieces.append((k, step + 1, nxt))
                split_cases = [[compiled(c) for c in cases(b)] if cases is not None else [] for _, _, b, _ in lost]
                retry = run([(problem, b) for (_, _, b, _), problems in zip(lost, split_cases) for problem in problems])
                pos = 0
                for (k, step, b, out), problems in zip(lost, split_cases):
                    outs, pos = retry[pos : pos + len(problems)], pos + len(problems)
                    if k not in live:
                        continue
                    rec = live[k]
                    ends = [next_box(b, [o], rec) for o in outs]
                    if problems and all(e is not None for e in ends):
                        rec["splits"] += len(problems) - 1
                        together = np.column_stack([np.min([e[:, 0] for e in ends], 0), np.max([e[:, 1] for e in ends], 0)])
                        if size(together) <= _MERGE * max(size(e) for e in ends):
                            ends = [together]  # the cases end close together: one part, not 2^steps
                        for nxt in ends:
                            record(k, step + 1, nxt)
                            pieces.append((k, step + 1, nxt))
                    elif rec["splits"] < max_splits and out.verdict != "violated":
                        rec["splits"] += 1
                        j = int(np.argmax((b[:, 1] - b[:, 0]) * weights))
                        mid = 0.5 * (b[j, 0] + b[j, 1])
                        for lo, hi in ((b[j, 0], mid), (mid, b[j, 1])):
                            half = b.copy()
                            half[j] = (lo, hi)
                            pieces.append((k, step, half))
                    else:
                        why = out.reason or f"the box grew more than {growth:g} times"
                        why = why.replace("step 1", f"step {step + 1}").replace("step 0", f"step {step}")
                        finish(k, "unknown", f"{why} (from the box of step {step}, after {rec['splits']} splits)")
                for k in [k for k in live if not any(p[0] == k for p in pieces)]:
                    finish(k, "verified")
    finally:
        if bar is not None:
            bar.close()
        journal_.close()
    return Result(names, box.to_dict(), [done[k] for k in sorted(done)], time.time() - started, settings)


def published(data=None) -> dict:
    """The authors' per-interval results (``published_results/``): counts and means over the
    rows ``lo, hi, SAFE|UNSAFE, total s, DNN s, branches, flowpipes`` of both campaigns (the
    files hold merge-conflict markers and range lists, which are skipped)."""
    rows = []
    folder = f1data.data_dir(data) / "published_results"
    for name in PUBLISHED:
        path = folder / name
        if not path.is_file():
            continue
        for line in path.read_text().splitlines():
            parts = [p.strip() for p in line.split(",")]
            if len(parts) == 7 and parts[2] in ("SAFE", "UNSAFE"):
                rows.append((float(parts[0]), float(parts[1]), parts[2] == "SAFE", *map(float, parts[3:])))
    if not rows:
        raise InputError(f"no per-interval rows in {folder} ({', '.join(PUBLISHED)})")
    a = np.array([(lo, hi, safe, t, nn, br, fp) for lo, hi, safe, t, nn, br, fp in rows], dtype=float)
    return {
        "intervals": len(a),
        "safe": int(a[:, 2].sum()),
        "avg_seconds": float(a[:, 3].mean()),
        "avg_nn_seconds": float(a[:, 4].mean()),
        "avg_branches": float(a[:, 5].mean()),
        "branches_range": [int(a[:, 5].min()), int(a[:, 5].max())],
        "avg_flowpipes": float(a[:, 6].mean()),
        "covered_width": float((a[:, 1] - a[:, 0]).sum()),
        "y1_range": [float(a[:, 0].min()), float(a[:, 1].max())],
    }


def row(result) -> dict:
    """The Table 1 figures of a result: intervals, average time and NN time per interval (s),
    average branches, coverage, total wall time (s)."""
    run = [c for c in result.cells if c.verdict != "falsified"]
    mean = lambda xs: float(np.mean(xs)) if xs else 0.0  # noqa: E731
    counts = {v: sum(c.verdict == v for c in result.cells) for v in ("verified", "unknown", "falsified")}
    return {
        "intervals": len(result.cells),
        **counts,
        "avg_seconds": mean([c.seconds for c in run]),
        "avg_nn_seconds": mean([c.nn_seconds for c in run]),
        "avg_branches": mean([c.branches for c in run]),
        "coverage": float(result.coverage),
        "wall_seconds": float(result.seconds),
    }


def table(result, data=None) -> str:
    """Our row next to the paper's Table 1 row and the published per-interval results."""
    ours = row(result)
    try:
        pub = published(data)
    except (InputError, OSError):
        pub = None
    lines = [
        f"{'F1/10':<26} {'intervals':>9} {'avg s':>9} {'avg NN s':>9} {'avg br':>7} {'coverage':>9} {'wall s':>9}",
        f"{'percver':<26} {ours['intervals']:>9} {ours['avg_seconds']:>9.2f} {ours['avg_nn_seconds']:>9.2f} "
        f"{ours['avg_branches']:>7.2f} {100 * ours['coverage']:>8.2f}% {ours['wall_seconds']:>9.0f}",
        f"{'paper (Table 1)':<26} {PAPER_ROW['intervals']:>9} {PAPER_ROW['avg_seconds']:>9.0f} {'':>9} "
        f"{PAPER_ROW['avg_branches']:>7.2f} {'':>9} {'':>9}",
    ]
    if pub is not None:
        lines.append(
            f"{'published (cov.= % SAFE)':<26} {pub['intervals']:>9} {pub['avg_seconds']:>9.0f} "
            f"{pub['avg_nn_seconds']:>9.0f} {pub['avg_branches']:>7.2f} "
            f"{100 * pub['safe'] / pub['intervals']:>8.2f}% {'':>9}"
        )
    return "\n".join(lines)


def save(result, out, data=None) -> dict:
    """``out/result.json`` (every cell) and ``out/row.json`` (the Table 1 figures, the paper's row,
    the published per-interval summary, unknown cells per step, the load average); returns the row record."""
    import os

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    result.to_json(str(folder / "result.json"))
    lost = np.bincount([c.steps_done for c in result.cells if c.verdict == "unknown"], minlength=1)
    try:
        pub = published(data)
    except (InputError, OSError):
        pub = None
    record = {
        "row": row(result),
        "paper": PAPER_ROW,
        "published": pub,
        "settings": result.settings,
        "unknown_steps": [[int(k), int(n)] for k, n in enumerate(lost) if n],
        "load_average": list(os.getloadavg()),
        "out": str(folder.resolve()),
    }
    (folder / "row.json").write_text(json.dumps(record, indent=1))
    return record
