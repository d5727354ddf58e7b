"""Figures of the F1/10 study: real vs simulated trajectories (paper Figure 6), control outputs
along a run (Figure 5), and the t_Delta curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from percver.cases.f1tenth import world
from percver.cases.f1tenth.dynamics import MAX_STEERING
from percver.errors import MissingDependencyError


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise MissingDependencyError("plots need matplotlib: pip install 'percver[plot]'") from None
    return plt


def _walls(ax, track):
    for (x0, y0), (x1, y1) in track.segments:
        ax.plot([x0, x1], [y0, y1], color="0.3", lw=1.5)


def _runs(ax, paths, crashed, color, label):
    for k, (xy, crash) in enumerate(zip(paths, crashed)):
        ax.plot(xy[:, 0], xy[:, 1], color=color, lw=2.6 if crash else 0.8, alpha=0.9, label=label if k == 0 else None)
        if crash:
            ax.plot(xy[-1, 0], xy[-1, 1], "x", color=color, ms=7, mew=2)


def trajectories(data, simulated, path, names=None, *, sim_label: str = "simulated with noise model") -> Path:
    """One panel per controller: recorded runs (poses of ``data``, black) and ``simulated`` runs
    (red) in the first turn; runs that crashed are bold and end in a cross."""
    plt = _pyplot()
    names = list(names or dict.fromkeys(data.controllers))
    cols = min(4, len(names))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.3 * cols, 4.0 * rows + 0.6), squeeze=False)
    track = world.square()
    for ax, name in zip(axes.flat, names):
        _walls(ax, track)
        real = [i for i, c in enumerate(data.controllers) if c == name]
        _runs(ax, [data.poses[data.run == i, :2] for i in real], data.crashed[real], "black", "real")
        sim = [i for i, c in enumerate(simulated.controllers) if c == name]
        _runs(ax, [simulated.states[simulated.run == i, :2] for i in sim], simulated.crashed[sim], "tab:red", sim_label)
        ax.set_xlim(-0.3, 3.8)
        ax.set_ylim(8.0, 20.3)
        ax.set_aspect("equal")
        ax.set_title(name.replace("_L21", ""), fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8)
    fig.suptitle("F1/10 first turn: real vs simulated runs (bold: crash)", fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def control_outputs(data, run: int, model_scans, controllers: dict, path) -> Path:
    """Steering along one run from canonical, noised (``model_scans``, N x 21 m) and real scans."""
    plt = _pyplot()
    rows = np.flatnonzero(data.run == run)
    controller = controllers[data.controllers[run]]
    t = data.time[rows]
    fig, ax = plt.subplots(figsize=(6, 3))
    for scans, label, style in (
        (data.canonical[rows], "canonical", ":"),
        (model_scans[rows], "noised", "-"),
        (data.real[rows], "real", "--"),
    ):
        ax.plot(t, np.degrees(MAX_STEERING) * controller.raw(scans), style, label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("steering (deg)")
    ax.set_title(f"run {run}, {data.controllers[run]}{' (crash)' if data.crashed[run] else ''}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def threshold_curve(curve, path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.semilogx(curve.thresholds[:-1], curve.errors[:-1], label="noised canonical vs real")
    ax.axhline(curve.errors[-1], color="0.5", ls=":", label="canonical (no knock-outs)")
    ax.axvline(curve.best, color="tab:red", ls="--", label=f"t* = {curve.best:.3g} m")
    ax.set_xlabel("t_Delta (m)")
    ax.set_ylabel("mean |error| per ray (m)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
