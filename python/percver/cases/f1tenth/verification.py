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

It runs in the engine (``pv.verify``): each cell's state is one Taylor model carried over all
steps, undecided knock-outs fork, and the adaptive splitter picks the cells and ``rebox`` (the
LiDAR remainders feed back and grow unless parts restart from their boxes; see ``pv.Adaptive``).
``cell=`` gives the paper's uniform cells instead (5e-5 in y1), each reboxed from the start.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import data as f1data
from percver.cases.f1tenth import dynamics, noise, world
from percver.errors import InputError

MARGIN = 0.15
INNER = world.WIDTH - MARGIN
GOAL_Y1 = 2.5
STEPS = 50
INIT = {"y1": (0.65, 0.85), "y2": (9.0, 9.0), "y3": (0.0, 0.0), "y4": (0.0, 0.0)}
# The published campaign's cells: 5e-5 in y1 (REFERENCE.md).
PAPER_CELL = 5e-5
# Taylor order of the uniform cells: in cells this small (and the boxes they are reboxed to),
# terms of degree 4 and 5 are mostly under the engine's cutoff, so order 3 decides the same
# cells with fewer forks at about half the cost of the engine's default 5 (bench/README.md,
# "F1/10 cost per cell").
CELL_ORDER = 3
# Table 1 of the paper, F1/10 row.
PAPER_ROW = {"intervals": 8236, "avg_seconds": 10733.0, "avg_branches": 6.88}
PUBLISHED = ("RESULTS_SUMMARY.txt", "RESULTS_SUMMARY_0.75_0.85.txt")


def plant():
    """The bicycle model in hallway-local coordinates, steering ``u`` held over 0.1 s."""
    import percver as pv

    return pv.Continuous(dynamics.equations("local", delta="u"), inputs=["u"], period=dynamics.PERIOD)


def perception(controller, noise_model=None, denoiser=None):
    """LiDAR -> [classifier, knock-out] -> [denoiser] -> controller, as a ``pv.Perception``.

    Without ``noise_model`` the controller reads the canonical scan (the loop without noise)."""
    import percver as pv

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
        knocked = [
            pv.where(pv.Expr.var(f"prob_{i}") >= float(noise_model.thresholds[i]), float(noise_model.knocked[i]), pv.Expr.var(f"scan_{i}"))
            for i in rays
        ]
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
    cell: float | None = None,
    steps: int = STEPS,
    data=None,
    **verify_kwargs,
):
    """Verify the loop from y1 in ``y1`` (the other initial values and the property are the
    original model's); returns a ``pv.Result``. ``noise_model=False`` verifies the loop without
    classifier and denoiser. The cells are the adaptive splitter's unless ``cell`` (metres of
    y1, e.g. :data:`PAPER_CELL`) asks for a uniform grid, which runs with ``rebox=True``,
    ``max_splits=64`` and ``order=CELL_ORDER`` unless given; ``verify_kwargs`` go to ``pv.verify``."""
    import percver as pv

    lo, hi = (float(v) for v in y1)
    if not lo <= hi:
        raise InputError(f"y1 range needs lo <= hi, got ({lo}, {hi})")
    loop = closed_loop(networks, noise_model=noise_model, controller=controller, data=data)
    init = {**INIT, "y1": (lo, hi)}
    if cell is not None:
        if not cell > 0:
            raise InputError(f"cell width must be positive, got {cell}")
        verify_kwargs = {"rebox": True, "max_splits": 64, "order": CELL_ORDER, "split": {"y1": cell}, **verify_kwargs}
    return pv.verify(loop, init, steps=steps, **property_(), **verify_kwargs)


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
