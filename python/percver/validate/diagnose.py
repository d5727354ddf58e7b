"""``diagnose(model, data)``: add the best effect, refit, repeat until no candidate helps."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from percver.errors import InputError
from percver.validate.effects import GaussianNoise
from percver.validate.fitting import parameter_intervals, plain, rank, refit
from percver.validate.learned import check_learn
from percver.validate.learned import learn as learned_step
from percver.validate.models import as_model
from percver.validate.regions import missing_pattern
from percver.validate.report import compare, json_default


# Lines of unexplained regions and dimensions in the text table (an image may have hundreds).
UNEXPLAINED_LINES = 10


@dataclass
class Step:
    """One added effect: its parameters after the joint refit, the in-sample error before and
    after, and the held-out share of the (then current) model's squared error it removed."""

    effect: str
    params: dict
    error_before: float
    error_after: float
    explained_fraction: float


class Diagnosis:
    """The outcome of ``diagnose``: the error-fall steps, the final model and what is left.

    ``unexplained`` lists regions and dimensions that still carry significant error, with
    their share of the final error (empty when the residual looks like noise);
    ``noise_sigma`` is the white-noise floor of the final model's residuals; ``learned`` is the
    ``Attempt`` of ``learn=True`` (None when nothing was left to learn or learning was off),
    kept as the last step when its held-out gain is significant.
    """

    def __init__(self, baseline, steps, final, rankings, noise_sigma, learned=None):
        self.baseline = baseline
        self.steps = steps
        self.final = final
        self.rankings = rankings
        self.noise_sigma = noise_sigma
        self.learned = learned
        self._intervals = {}
        where = final.where()
        self.unexplained = [
            {"kind": "region", "where": r.describe(), "bounds": r.bounds, "share": r.share, "lift": r.lift}
            for r in where.significant_regions
        ] + [{"kind": "dimension", "where": d.name, "share": d.share} for d in where.significant_dimensions]
        missing = missing_pattern(final.model, final.predicted, final.evaluation.measured, final.evaluation)
        if missing is not None:
            self.unexplained.append(missing)

    @property
    def baseline_error(self) -> float:
        return self.baseline.error

    @property
    def final_error(self) -> float:
        return self.final.error

    @property
    def final_model(self):
        return self.final.model

    @property
    def effects(self) -> list:
        return [step.effect for step in self.steps]

    # ---------------------------------------------------------------- the model verify checks
    @property
    def model(self):
        """The diagnosed model as ``verify`` takes it, with the fitted parameter values: for a plant
        a ``pv.Discrete``/``pv.Continuous`` (``pv.ClosedLoop(diagnosis.model, stages=[...])``), for
        a LiDAR (or a camera rendered by expressions) the expressions a ``pv.Stage`` takes, for a
        camera rendered by a generator network a ``CameraSensor`` (``*model.stages(output="image")``).
        ``system(...)`` adds the parameters' confidence intervals and the residual."""
        return self.system()

    @property
    def domain(self):
        """Where the model was validated: per state, the range the measurements cover (a ``Domain``)."""
        from percver.validate.verifiable import Domain

        return Domain.of(self.final_model.state_names, self.final.evaluation.states)

    def intervals(self, level: float = 0.95, *, draws: int = 100, seed: int = 0) -> dict:
        """Bootstrap confidence intervals of the fitted parameters, ``{effect index: {parameter:
        (lo, hi)}}`` in the order of ``final_model.effects`` (refits on resampled trajectories;
        computed once per level, draws and seed)."""
        key = (level, draws, seed)
        if key not in self._intervals:
            self._intervals[key] = parameter_intervals(self.final_model, self.final.evaluation, level=level, draws=draws, seed=seed)
        return self._intervals[key]

    def system(self, uncertainty=None, residual=None, *, per: str = "run", onnx=None, draws: int = 100, seed: int = 0):
        """The diagnosed model for verification (see ``percver.validate.verifiable``).

        ``uncertainty="ci95"`` (or "ci99", or a level such as 0.9) turns every fitted parameter
        into a ``pv.uncertain`` range, its bootstrap confidence interval, so that a proof holds
        for every parameter the data allows; None keeps the fitted values. The ranges are held
        over a run (``per="run"``: a friction is a constant of the car, and ``verify`` keeps the
        dependency on it), or with ``per="step"`` re-drawn each step (a parameter that drifts:
        looser, and it covers more). ``residual="max"``
        adds the largest measured residual of each state (ray) as a bounded disturbance every
        step, ``residual=0.999`` that quantile (a statistical bound, not a worst case). The
        result's ``validation`` records all of it with the validated domain.

        A diagnosis that ends with a learned noise model of a sensor gives a ``LearnedSensor``:
        ``*model.stages(output="scan")`` are the loop's stages for the sensor, its network the
        paper's g_n; ``onnx=DIR`` writes the network there as ONNX and the stage reads the file.
        """
        from percver.validate import verifiable

        if per not in ("run", "step"):
            raise InputError(f"per={per!r}: use 'run' (parameters held over a run) or 'step' (re-drawn each step)")
        level = _level(uncertainty)
        ranges = {} if level is None else self.intervals(level, draws=draws, seed=seed)
        bounds, kind = (None, None) if residual is None else verifiable.residual_bounds(self.final, residual)
        model = self.final_model
        learned = model.learned if self.learned is not None and self.learned.claimed else None
        base = model.base if learned is not None else model
        if base.kind == "dynamics":
            if learned is not None:
                raise verifiable.NoSetSemanticsError(
                    "the diagnosis ends with a learned noise model of the dynamics: learned models enter a loop as "
                    "sensor stages (the paper's g_n), not as plants. Diagnose the plant with learn=False and bound "
                    "what is left with system(residual='max')"
                )
            return verifiable.dynamics_system(model, ranges, bounds, kind, level, self.domain, per)
        # The residual of a learned model is added after its network.
        canonical_bounds = None if learned is not None else bounds
        if base.kind == "lidar":
            component = verifiable.lidar_component(base, ranges, canonical_bounds, kind, level, self.domain, per)
        elif base.kind == "image":
            component = verifiable.camera_component(base, ranges, canonical_bounds, kind, level, self.domain, per)
        else:
            component = verifiable.expression_component(base, canonical_bounds, kind, level, self.domain, per)
        if learned is None:
            return component
        return verifiable.learned_sensor(component, learned, bounds, kind, base.measurement_names, onnx)

    def table(self) -> str:
        lines = [f"baseline {self.baseline.metric}: {self.baseline_error:.4g}"]
        for i, s in enumerate(self.steps, 1):
            params = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in s.params.items())
            lines.append(
                f"step {i}: + {s.effect:<20} {s.error_before:.4g} -> {s.error_after:.4g} "
                f"(held-out gain {s.explained_fraction:.1%})  {params}"
            )
        lines.append(
            f"final {self.final.metric}: {self.final_error:.4g} ({self.final_error / max(self.baseline_error, 1e-300):.1%} of baseline)"
        )
        if self.noise_sigma is not None:
            lines.append(f"noise floor sigma: {self.noise_sigma:.4g}")
        if self.learned is not None and not self.learned.claimed:
            a = self.learned
            lines.append(f"learned_{a.kind} not kept: held-out gain {a.gain:.1%} [{a.ci[0]:.1%}, {a.ci[1]:.1%}]")
        for u in self.unexplained[:UNEXPLAINED_LINES]:
            of = "of the lost echoes" if u["kind"] == "missing" else "of the remaining error"
            lines.append(f"unexplained {u['kind']}: {u['where']} ({u['share']:.1%} {of})")
        if len(self.unexplained) > UNEXPLAINED_LINES:
            lines.append(f"... and {len(self.unexplained) - UNEXPLAINED_LINES} more unexplained regions or dimensions")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()

    def __repr__(self) -> str:
        return f"Diagnosis({' + '.join(self.effects) or 'no effect'}: {self.baseline_error:.4g} -> {self.final_error:.4g})"

    def plot(self, path=None):
        """The error-fall curve (a matplotlib figure; saved as PNG when ``path`` is given)."""
        from percver.validate import html

        return html.error_fall(self, path)

    def to_dict(self) -> dict:
        return {
            "baseline_error": self.baseline_error,
            "final_error": self.final_error,
            "metric": self.final.metric,
            "steps": [{**asdict(s), "params": plain(s.params)} for s in self.steps],
            "final_model": self.final_model.describe(),
            "noise_sigma": self.noise_sigma,
            "unexplained": self.unexplained,
            "learned": None if self.learned is None else self.learned.to_dict(),
            "rankings": [r.to_dict() for r in self.rankings],
        }

    def to_json(self, path=None) -> str:
        text = json.dumps(self.to_dict(), indent=2, default=json_default)
        if path is not None:
            Path(path).write_text(text)
        return text

    def to_html(self, directory) -> Path:
        from percver.validate import html

        return html.write_diagnosis(self, directory)


def diagnose(
    model,
    data,
    effects=None,
    *,
    max_steps: int = 6,
    folds: int = 3,
    bootstrap: int = 200,
    min_gain: float = 0.05,
    metric: str = "rmse",
    learn: bool | str = False,
    learn_options: dict | None = None,
    seed: int = 0,
    progress: bool = False,
) -> Diagnosis:
    """Compare, explain, add the best claimed effect, refit all added effects, repeat.

    An effect is added when it removes at least ``min_gain`` of the current model's squared
    error on held-out data (lower end of its bootstrap interval), so a small effect is still
    found once a dominant one is modelled. Systematic effects are preferred to random ones
    (dropout), and random ones are refused where their events crowd into one region.

    ``learn=True`` adds, when a localized residual is left unexplained, the paper's learned
    noise model as a last step (``learned_knockout`` or ``learned_generative``, chosen from
    the residual; ``learn="knockout"`` or ``"generative"`` forces one), under the same held-out
    rule (see ``percver.validate.learned``; needs torch). ``learn_options`` sets its network
    and training: ``hidden``, ``epochs``, ``batch``, ``lr``, ``seed``, ``threads``, ...
    """
    check_learn(learn, learn_options)
    model = as_model(model, data)
    evaluation = model.evaluate(data)
    baseline = compare(model, data, metric=metric)
    bar = _progress(progress)
    current, steps, rankings = model, [], []
    try:
        for _ in range(max_steps):
            ranking = rank(current, evaluation, effects, folds=folds, bootstrap=bootstrap, min_gain=min_gain, seed=seed, progress=bar)
            rankings.append(ranking)
            if not ranking or not ranking[0].claimed:
                break
            best = ranking[0]
            before = compare(current, data, metric=metric).error
            index = current.insertion_index(best.effect)
            current = refit(current.with_effect(best.effect), evaluation)
            after = compare(current, data, metric=metric).error
            steps.append(Step(best.name, dict(current.effects[index].params), before, after, best.gain))
            if bar is not None:
                bar.set_postfix_str(f"+{best.name}")
    finally:
        if bar is not None:
            bar.close()
    final = compare(current, data, metric=metric)
    attempt = None
    if learn and (final.where().significant_regions or final.where().significant_dimensions):
        # With progress on, training shows a bar over its epochs with the time left.
        options = {"progress": True, **(learn_options or {})} if progress else learn_options
        learned, attempt = learned_step(
            current, evaluation, final, learn, options, folds=folds, bootstrap=bootstrap, min_gain=min_gain, seed=seed
        )
        if learned is not None:
            after = compare(learned, data, metric=metric)
            steps.append(Step(learned.learned.name, dict(learned.learned.params), final.error, after.error, attempt.gain))
            current, final = learned, after
    noise = None
    if current.kind in GaussianNoise.kinds:
        noise = GaussianNoise().fit_stochastic(current, evaluation, final.predicted).params["sigma"]
    return Diagnosis(baseline, steps, final, rankings, noise, attempt)


def _level(uncertainty):
    """``uncertainty=`` as a confidence level: None, "ci95"-style names or a number in (0, 1)."""
    if uncertainty is None:
        return None
    if isinstance(uncertainty, str) and uncertainty.startswith("ci") and uncertainty[2:].isdigit():
        level = int(uncertainty[2:]) / 100
    elif isinstance(uncertainty, float):
        level = uncertainty
    else:
        level = -1.0
    if not 0 < level < 1:
        raise InputError(f"uncertainty={uncertainty!r}: use None, 'ci95', 'ci99' or a confidence level in (0, 1)")
    return level


def _progress(enabled):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(desc="diagnose (candidates fitted)", unit="fit")
