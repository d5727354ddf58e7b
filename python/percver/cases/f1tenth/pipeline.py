"""The paper's modelling pipeline on recorded runs: poses -> training set -> labels -> metrics.

``training_set`` turns runs (raw scans, steering, run ids, times; never the true states) and
the particle filter's poses into the paper's D = {(x_i, y_i)}: estimated poses and the real
21-ray scans. The metrics are those of section 4.3 / Table 2: whole-scan accuracy of the
knock-out labels, the control-based error (each run's own controller on real vs modelled
scans), and the trajectory-based metric (share of safe runs, real vs simulated with the noise
model). ``simulate_model`` drives the canonical car with a noise model and/or denoiser.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import loop, noise, world
from percver.cases.f1tenth.dynamics import MAX_STEERING
from percver.errors import InputError, MeasurementError
from percver.measurements import Measurements


@dataclass
class TrainingSet:
    """Estimated poses (N x 3 world: x, y, theta) with the real 21-ray scans (N x 21, metres)
    they were measured in; ``run`` and ``time`` per row; per run the controller name and
    whether it crashed."""

    poses: np.ndarray
    real: np.ndarray
    run: np.ndarray
    time: np.ndarray
    controllers: list
    crashed: np.ndarray
    meta: dict = field(default_factory=dict)
    _canonical: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def local(self) -> np.ndarray:
        return world.to_local(self.poses)

    @property
    def canonical(self) -> np.ndarray:
        """g_c at the estimated poses (N x 21, metres), on the square loop."""
        if self._canonical is None:
            self._canonical = world.controller_lidar().scan(world.square(), self.poses)
        return self._canonical

    def inputs(self) -> np.ndarray:
        """The classifier's inputs: normalised canonical rays and pose features (N x 24)."""
        return np.column_stack([world.normalise(self.canonical), world.pose_features(self.local)])

    def row_controllers(self) -> np.ndarray:
        return np.asarray(self.controllers, dtype=object)[self.run]

    def select_runs(self, runs) -> "TrainingSet":
        runs = np.asarray(sorted(set(int(r) for r in runs)), dtype=int)
        rows = self.rows_of(runs)
        renumber = {int(r): i for i, r in enumerate(runs)}
        return TrainingSet(
            self.poses[rows],
            self.real[rows],
            np.array([renumber[int(r)] for r in self.run[rows]], dtype=int),
            self.time[rows],
            [self.controllers[r] for r in runs],
            self.crashed[runs],
            dict(self.meta),
            None if self._canonical is None else self._canonical[rows],
        )

    def split_runs(self, test_share: float = 0.2, seed: int = 0) -> tuple[list, list]:
        """Run indices (train, test), the test runs drawn per controller."""
        rng = np.random.default_rng(seed)
        test = set()
        for name in dict.fromkeys(self.controllers):
            runs = [i for i, c in enumerate(self.controllers) if c == name]
            test.update(rng.choice(runs, size=int(round(test_share * len(runs))), replace=False).tolist())
        return [i for i in range(len(self.controllers)) if i not in test], sorted(test)

    def rows_of(self, runs) -> np.ndarray:
        """Row mask of ``runs`` (``select_runs`` keeps exactly these rows, in order)."""
        return np.isin(self.run, np.asarray(list(runs), dtype=int))

    def to_measurements(self) -> Measurements:
        meta = dict(self.meta)
        meta["runs"] = [{"id": i, "controller": c, "crashed": bool(k)} for i, (c, k) in enumerate(zip(self.controllers, self.crashed))]
        return Measurements(
            self.poses,
            self.real,
            trajectory=self.run,
            time=self.time,
            state_names=("x", "y", "theta"),
            measurement_names=world.controller_lidar(),
            meta=meta,
        )

    @classmethod
    def from_measurements(cls, data: Measurements) -> "TrainingSet":
        runs = data.meta.get("runs")
        if not runs or data.trajectory is None or data.measurements is None or data.measurements.shape[1] != 21:
            raise MeasurementError(
                f"{data.source or 'the measurements'} are not an F1/10 training set: need 21-ray scans, "
                "'trajectory', 'time' and meta['runs'] as written by percver cases f1tenth estimate"
            )
        meta = {k: v for k, v in data.meta.items() if k != "runs"}
        return cls(
            data.state_matrix(("x", "y", "theta")),
            data.measurements,
            data.trajectory,
            data.time,
            [r["controller"] for r in runs],
            np.array([bool(r["crashed"]) for r in runs]),
            meta,
        )


def training_set(runs: loop.Runs, poses) -> TrainingSet:
    """D from recorded runs and the estimated poses of their scans (``particle_filter.PoseEstimate``
    or an N x 3 array)."""
    poses = getattr(poses, "poses", poses)
    if len(poses) != len(runs.run):
        raise InputError(f"{len(poses)} poses for {len(runs.run)} scans: estimate the poses of these runs")
    return TrainingSet(
        np.asarray(poses)[:, :3],
        world.controller_view(runs.scans),
        np.asarray(runs.run),
        np.asarray(runs.time),
        list(runs.controllers),
        runs.crashed,
        dict(runs.meta),
    )


# ------------------------------------------------------------------------------------------ metrics
def whole_scan_accuracy(predicted, labels) -> float:
    """Share of scans whose 21 knock-out decisions all equal the labels."""
    return float(np.mean(np.all(np.asarray(predicted) == np.asarray(labels), axis=1)))


def control_outputs(data: TrainingSet, scans, controllers: dict) -> np.ndarray:
    """Each row's own-run controller's raw output on ``scans`` (N x 21, metres)."""
    out = np.empty(len(data))
    names = data.row_controllers()
    for name in dict.fromkeys(data.controllers):
        rows = names == name
        out[rows] = controllers[name].raw(scans[rows])
    return out


def control_error(data: TrainingSet, scans, controllers: dict) -> dict:
    """The control-based metric: |h_c(real) - h_c(model)| per scan, h_c the run's controller.

    ``sum`` is in network-output units summed over all scans (the scale of the paper's
    Table 2); ``mean_deg`` and ``max_deg`` are steering degrees."""
    difference = np.abs(control_outputs(data, data.real, controllers) - control_outputs(data, scans, controllers))
    degrees = difference * np.degrees(MAX_STEERING)
    return {"sum": float(difference.sum()), "mean_deg": float(degrees.mean()), "max_deg": float(degrees.max()), "scans": len(data)}


def _nonempty(data: TrainingSet, what: str) -> None:
    if len(data) == 0:
        raise InputError(f"{what} needs scans, the training set given has none (a test split of too few runs?)")


def evaluate_noise_model(model: noise.NoiseModel, data: TrainingSet, labels, controllers: dict) -> dict:
    """Whole-scan accuracy, ray accuracy and control error of ``model`` on ``data``."""
    _nonempty(data, "evaluating a noise model")
    canonical = world.normalise(data.canonical)
    features = world.pose_features(data.local)
    knocked = model.knockouts(canonical, features)
    noised = world.denormalise(np.where(knocked, noise.KNOCKED, canonical))
    return {
        "model": model.name,
        "whole_scan_accuracy": whole_scan_accuracy(knocked, labels),
        "ray_accuracy": float(np.mean(knocked == labels)),
        "knocked_share": float(knocked.mean()),
        "label_share": float(np.mean(labels)),
        "control_error": control_error(data, noised, controllers),
    }


def evaluate_denoiser(denoiser: noise.Denoiser, data: TrainingSet, controllers: dict) -> dict:
    """How close the denoised real scans come to the canonical ones, in range and in control."""
    _nonempty(data, "evaluating a denoiser")
    denoised = world.denormalise(denoiser(world.normalise(data.real)))
    on_canonical = control_outputs(data, data.canonical, controllers)
    return {
        "model": denoiser.name,
        "mean_range_error_m": float(np.abs(denoised - data.canonical).mean()),
        "real_range_error_m": float(np.abs(data.real - data.canonical).mean()),
        "control_error_vs_canonical_deg": float(
            np.degrees(MAX_STEERING) * np.abs(control_outputs(data, denoised, controllers) - on_canonical).mean()
        ),
        "real_control_error_vs_canonical_deg": float(
            np.degrees(MAX_STEERING) * np.abs(control_outputs(data, data.real, controllers) - on_canonical).mean()
        ),
    }


# ------------------------------------------------------------------------------------------ closed loop
def model_sensor(noise_model: noise.NoiseModel | None = None, denoiser: noise.Denoiser | None = None, track=None):
    """``sense`` for ``loop.drive``: canonical 21 rays, then knock-outs, then the denoiser."""
    track = track or world.square()
    lidar = world.controller_lidar()

    def sense(states, rng):
        scans = world.normalise(lidar.scan(track, states))
        if noise_model is not None:
            scans = noise_model.apply(scans, world.pose_features(world.to_local(states)))
        if denoiser is not None:
            scans = denoiser(scans)
        ranges = world.denormalise(scans)
        return ranges, ranges

    return sense


def start_states(data: TrainingSet) -> np.ndarray:
    """Each run's first estimated pose, at rest (the runs start standing)."""
    first = np.array([np.flatnonzero(data.run == r)[0] for r in range(len(data.controllers))])
    return np.column_stack([data.poses[first], np.zeros(len(first))])


def simulate_model(starts, names, controllers: dict, noise_model=None, denoiser=None, *, periods: int = loop.PERIODS) -> loop.Runs:
    """Drive the canonical car (10 Hz) from ``starts`` with the controllers ``names`` (one per run)."""
    missing = sorted(set(names) - set(controllers))
    if missing:
        raise InputError(f"no controller loaded for {missing}")
    return loop.drive(starts, [controllers[n] for n in names], model_sensor(noise_model, denoiser), rate=10.0, periods=periods)


def trajectory_metric(data: TrainingSet, simulated: loop.Runs, stats=None) -> dict:
    """Percentage of safe runs per controller: recorded runs vs simulation with the noise model
    (and the paper's real runs when ``stats`` from ``data.real_statistics`` is given)."""
    out = {}
    sim = simulated.safe_share()
    for name in dict.fromkeys(data.controllers):
        flags = [not c for n, c in zip(data.controllers, data.crashed) if n == name]
        row = {"runs": len(flags), "real_safe": 100.0 * float(np.mean(flags)), "sim_safe": sim.get(name)}
        if stats is not None:
            paper = stats.crashes.get(ctl.short_name(name))
            row["paper_real_safe"] = None if paper is None else 100.0 * (1 - float(np.mean(paper)))
        out[name] = row
    return out
