"""The paper's state-estimation metric for the Mountain Car models (section 4.3, section 5.1, Appendix A).

The real system runs in closed loop: true images (gymnasium, PIL contrast, the paper's blur) ->
estimator -> controller -> dynamics. At every state it visits, the estimator also reads the
model's image of that state (generator, then the contrast and/or blur network), and the metric is
``|h_e(true image) - h_e(model image)|``, over every step of every trajectory until the goal.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from percver.cases.mountain_car import dynamics
from percver.cases.mountain_car.camera import camera
from percver.cases.mountain_car.networks import Networks, load
from percver.errors import InputError, MissingDependencyError

# "All errors are bounded within a small range; although blur errors have a longer tail, the error
# is bounded by 0.09" (section 5.1). The paper gives no other number.
PAPER_BOUNDS = {"blur": 0.09}
# The single trajectories of the paper's figures: (p0, noise parameters) per panel.
SCENARIOS = {
    "canonical": [(-0.53, {}), (-0.4, {})],
    "contrast": [(-0.5, {"delta_c": 0.3}), (-0.5, {"delta_c": 1.06}), (-0.5, {"delta_c": 2.0})],
    "blur": [(-0.5, {"delta_b": 0.0}), (-0.5, {"delta_b": 0.15}), (-0.5, {"delta_b": 0.3})],
    "composite": [(-0.4, {"delta_c": 0.5, "delta_b": 0.15}), (-0.59, {"delta_c": 0.5, "delta_b": 0.15})],
}
FIGURES = {
    "canonical": "the paper's appendix figure of the canonical model",
    "contrast": "the paper's Figure 4a and appendix figure of the contrast model",
    "blur": "the paper's Figure 4b and appendix figure of the blur model",
    "composite": "the paper's appendix figure of the composite model",
}


@dataclass
class Runs:
    """Closed-loop runs of one noise kind: states, both estimates per step, and the noise of each run."""

    noise: str
    trajectories: dynamics.Trajectories
    p_hat_true: np.ndarray
    p_hat_model: np.ndarray
    params: dict

    @property
    def errors(self) -> np.ndarray:
        """|h_e(true image) - h_e(model image)| over every step taken."""
        return np.abs(self.p_hat_true - self.p_hat_model)[self.trajectories.active]

    def summary(self) -> dict:
        errors = self.errors
        active = self.trajectories.active
        truth = self.trajectories.p[:, :-1]
        return {
            "trajectories": len(self.trajectories.p), "samples": int(errors.size),
            "max": float(errors.max()), "mean": float(errors.mean()), "p95": float(np.percentile(errors, 95)),
            "estimate_error_true_images": float(np.abs(self.p_hat_true - truth)[active].mean()),
            "estimate_error_model_images": float(np.abs(self.p_hat_model - truth)[active].mean()),
            "closed_loop_safe_fraction": float(self.trajectories.safe.mean()),
            **({"paper_bound": PAPER_BOUNDS[self.noise]} if self.noise in PAPER_BOUNDS else {}),
        }  # fmt: skip


def run(networks: Networks, noise: str, p0, params: dict, *, steps: int = dynamics.STEPS, on_step=None) -> Runs:
    """Closed loop on true images from ``p0`` (n,) with per-run noise ``params`` ({"delta_c": (n,), ...})."""
    cam = camera()
    p0 = np.atleast_1d(np.asarray(p0, dtype=float))
    n = len(p0)
    params = {key: np.broadcast_to(np.asarray(value, dtype=float), (n,)) for key, value in params.items()}
    p_hat_true = np.full((n, steps), np.nan)
    p_hat_model = np.full((n, steps), np.nan)

    def controller(k, p, v, active):
        at = {key: value[active] for key, value in params.items()}
        p_hat_true[active, k] = networks.estimate(cam.observe(p[active], **at))
        p_hat_model[active, k] = networks.estimate(networks.images(p[active], **at))
        u = np.zeros(n)
        u[active] = networks.control(p_hat_true[active, k], v[active])
        return u

    trajectories = dynamics.simulate(p0, controller, steps=steps, on_step=on_step)
    return Runs(noise, trajectories, p_hat_true, p_hat_model, {k: np.asarray(v) for k, v in params.items()})


def _sample(noise: str, n: int, rng) -> tuple[np.ndarray, dict]:
    row = dynamics.noise_row(noise)
    p0 = rng.uniform(*row.pop("p0"), n)
    return p0, {key: rng.uniform(lo, hi, n) for key, (lo, hi) in row.items()}


@dataclass
class Evaluation:
    """Per noise kind: the random runs (histograms, summary) and the figure scenarios."""

    networks: str
    runs: dict
    scenarios: dict
    settings: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready numbers: per noise max, mean and 95th percentile of the estimate difference."""
        return {
            "networks": self.networks, **self.settings,
            "metric": "|h_e(true image) - h_e(model image)| at every step of closed-loop runs on true images",
            "noises": {noise: runs.summary() for noise, runs in self.runs.items()},
            "paper": {"blur": {"max": PAPER_BOUNDS["blur"], "source": "section 5.1: blur errors bounded by 0.09"}},
        }  # fmt: skip

    def to_json(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.summary(), indent=2) + "\n")
        return path

    def table(self) -> str:
        lines = [f"state-estimation metric, networks: {self.networks}",
                 f"{'noise':<10} {'runs':>5} {'samples':>8} {'max':>7} {'mean':>7} {'p95':>7} {'paper max':>9} {'safe':>6}"]  # fmt: skip
        for noise, runs in self.runs.items():
            s = runs.summary()
            paper = f"{s['paper_bound']:.2f}" if "paper_bound" in s else "-"
            lines.append(f"{noise:<10} {s['trajectories']:>5} {s['samples']:>8} {s['max']:>7.4f} {s['mean']:>7.4f} "
                         f"{s['p95']:>7.4f} {paper:>9} {s['closed_loop_safe_fraction']:>6.1%}")  # fmt: skip
        return "\n".join(lines)

    def plot(self, out) -> list[Path]:
        """PNG files in ``out``: one per noise kind (its scenarios and error histogram), ``figure4.png``
        (low contrast, high blur, histogram as the paper's Figure 4) and ``histograms.png``."""
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            raise MissingDependencyError("plots need matplotlib: pip install 'percver[plot]'") from None
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for noise, runs in self.runs.items():
            scenarios = self.scenarios.get(noise)
            panels = (len(SCENARIOS[noise]) if scenarios is not None else 0) + 1
            fig, axes = plt.subplots(1, panels, figsize=(4.2 * panels, 3.4), squeeze=False)
            for i in range(panels - 1):
                _trajectory(axes[0, i], scenarios, i)
            _histogram(axes[0, -1], {noise: runs})
            fig.suptitle(f"{noise} model, networks {self.networks} (cf. {FIGURES[noise]})", fontsize=10)
            written.append(_save(fig, out / f"trajectories_{noise}.png", plt))
        if {"contrast", "blur"} <= set(self.scenarios) and {"contrast", "blur"} <= set(self.runs):
            fig, axes = plt.subplots(1, 3, figsize=(12.6, 3.4))
            _trajectory(axes[0], self.scenarios["contrast"], 0)
            _trajectory(axes[1], self.scenarios["blur"], 2)
            _histogram(axes[2], {k: self.runs[k] for k in ("contrast", "blur")})
            fig.suptitle(f"cf. the paper's Figure 4, networks {self.networks}", fontsize=10)
            written.append(_save(fig, out / "figure4.png", plt))
        fig, ax = plt.subplots(figsize=(5, 3.6))
        _histogram(ax, self.runs)
        written.append(_save(fig, out / "histograms.png", plt))
        return written


def _save(fig, path: Path, plt) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _trajectory(ax, scenarios: Runs, i: int) -> None:
    active = scenarios.trajectories.active[i]
    k = np.arange(active.sum())
    ax.plot(k, scenarios.trajectories.p[i, :-1][active], color="0.6", lw=1, label="true position")
    ax.plot(k, scenarios.p_hat_true[i][active], lw=1.5, label="estimate, true images")
    ax.plot(k, scenarios.p_hat_model[i][active], lw=1.5, ls="--", label="estimate, model images")
    noise = ", ".join(f"{name} = {values[i]:g}" for name, values in scenarios.params.items())
    ax.set_title(f"p0 = {scenarios.trajectories.p[i, 0]:g}" + (f", {noise}" if noise else ""), fontsize=9)
    ax.set_xlabel("step")
    ax.set_ylabel("position")
    ax.legend(fontsize=7)


def _histogram(ax, runs: dict) -> None:
    top = max(float(r.errors.max()) for r in runs.values())
    bins = np.linspace(0.0, max(top, 1e-6), 40)
    for noise, r in runs.items():
        ax.hist(r.errors, bins=bins, alpha=0.55, label=f"{noise} (max {r.errors.max():.3f})")
    if "blur" in runs:
        ax.axvline(PAPER_BOUNDS["blur"], color="k", ls=":", lw=1, label="paper's blur bound 0.09")
    ax.set_yscale("log")
    ax.set_xlabel("|estimate(true image) - estimate(model image)|")
    ax.set_ylabel("steps")
    ax.legend(fontsize=7)


def evaluate(
    networks="ours",
    *,
    noises=dynamics.NOISES,
    trajectories: int = 1000,
    steps: int = dynamics.STEPS,
    seed: int = 0,
    controller=None,
    shared=None,
    scenarios: bool = True,
    out=None,
    progress: bool = True,
) -> Evaluation:
    """The state-estimation metric of ``networks`` ("ours", "paper", a directory, or :class:`Networks`).

    Per noise kind in ``noises``: ``trajectories`` runs from p0 and noise parameters drawn uniformly
    from the row's ranges (:data:`~percver.cases.mountain_car.dynamics.ROWS`), plus the single runs
    of the paper's figures (``scenarios``). ``out``: write ``summary.json`` and the plots there.
    """
    unknown = sorted(set(noises) - set(dynamics.NOISES))
    if unknown:
        raise InputError(f"unknown noise kind(s) {unknown}; choose among {list(dynamics.NOISES)}")
    if trajectories < 1:
        raise InputError(f"trajectories must be at least 1, got {trajectories}")
    chosen = load(networks, controller=controller, shared=shared)
    rng = np.random.default_rng(seed)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(noises) * steps * (2 if scenarios else 1), desc="evaluate", unit="step")
    tick = None if bar is None else (lambda k: bar.update(1))
    results, figures = {}, {}
    try:
        for noise in noises:
            if bar is not None:
                bar.set_postfix(noise=noise)
            p0, params = _sample(noise, trajectories, rng)
            results[noise] = run(chosen, noise, p0, params, steps=steps, on_step=tick)
            _finish(bar, steps, results[noise])
            if scenarios:
                starts = [p for p, _ in SCENARIOS[noise]]
                params = {key: [s[key] for _, s in SCENARIOS[noise]] for key in SCENARIOS[noise][0][1]}
                figures[noise] = run(chosen, noise, starts, params, steps=steps, on_step=tick)
                _finish(bar, steps, figures[noise])
    finally:
        if bar is not None:
            bar.close()
    settings = {"controller": str(controller) if controller is not None else "same set", "trajectories": trajectories,
                "steps": steps, "seed": seed}  # fmt: skip
    evaluation = Evaluation(chosen.name, results, figures, settings)
    if out is not None:
        evaluation.to_json(Path(out) / "summary.json")
        evaluation.plot(out)
    return evaluation


def _finish(bar, steps: int, runs: Runs) -> None:
    """Count the steps a batch did not take (all its runs reached the goal early)."""
    if bar is not None:
        taken = int(runs.trajectories.active.any(axis=0).sum())
        bar.update(steps - taken)
