"""A stand-in for the real F1/10 runs: a scanner with realistic faults on the square loop.

The original real traces are not public; what is known of them (``data.real_statistics``)
calibrates this simulator. The "real" scanner is the full sensor (1081 rays, 40 Hz, 10 m) on
the canonical walls, plus what the canonical model does not know:

- glossy walls: a ray meeting any wall beyond ``gloss_deg`` of incidence is mirrored away and
  returns nothing (a soft edge of ``softness_deg`` makes rays near a limit flicker);
- reflective panels near the first turn (``PANELS``): metal mirrors rays away beyond a much
  lower incidence, glass lets rays through below one (windows, a glass door); a panel either
  returns nothing or saturates at the range limit;
- range noise growing with range, mixed pixels at depth edges, random outliers and lost
  echoes ("invalid returns").

The real car's steering servo also lags its commands a little (``steering_lag``), which the
canonical car does not. Raw readings are metres rounded to millimetres; 0.0 marks no return
(anything up to ``world.NO_ECHO``), 10.0 a reading at the limit. The controllers read
``world.controller_view`` of the raw scan. Which rays a panel swallows depends on where the ray
hits and at what angle: a discontinuous function of the pose, the adversarial noise of the paper.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from percver.cases.f1tenth import controllers as ctl
from percver.cases.f1tenth import loop, world
from percver.cases.f1tenth.data import real_statistics
from percver.errors import InputError
from percver.measurements import Measurements
from percver.sensors.lidar import Track


@dataclass(frozen=True)
class Panel:
    """A stretch of wall that loses rays: wall coordinates ``start``..``end`` (m, ``Track.wall_point``).

    ``material`` "metal" mirrors rays beyond ``threshold_deg`` of incidence away; "glass" lets
    rays below ``threshold_deg`` through (into a large room: no echo). ``echo`` "none" (no
    return) or "max" (the reading saturates at the range limit). ``fixed`` panels are part of
    the building and stay when the others are covered.
    """

    start: float
    end: float
    threshold_deg: float
    material: str = "metal"
    echo: str = "none"
    fixed: bool = False

    def __post_init__(self):
        if self.material not in ("metal", "glass") or self.echo not in ("none", "max"):
            raise InputError(
                f"panel material '{self.material}' / echo '{self.echo}': use material 'metal' or 'glass' and echo 'none' or 'max'"
            )
        if not self.start < self.end:
            raise InputError(f"panel spans wall coordinates {self.start}..{self.end}: start must be below end")


def _wall(segment: int, lo: float, hi: float) -> tuple:
    """Wall coordinates of metres ``lo``..``hi`` along segment ``segment`` of the square loop."""
    offset = world.square().offsets[segment]
    return offset + lo, offset + hi


# Square-loop segments: 0 west outer (y up), 1 north outer (x right), 4 west inner, 5 north inner.
# The reflective surfaces of the hall, placed and sized by a random search that matched the
# simulated runs to the real statistics (reflected rays per scan, crashes per controller).
PANELS = (
    Panel(*_wall(0, 6.0, 20.0), 6.5, "glass", "none", fixed=True),  # windows along the outer wall
    Panel(*_wall(1, 0.1, 1.4), 8.0, "glass", "max"),  # glass door at the end of the first hallway
    Panel(*_wall(4, 13.0, 16.5), 53.0, "metal", "none"),  # metal cabinets on the inner wall before the turn
)


@dataclass(frozen=True)
class RealWorld:
    """The hidden environment; ``covered()`` is the same hall with the panels covered."""

    panels: tuple = PANELS
    gloss_deg: float | tuple = 73.0  # one limit for all walls, or one per track segment
    # Rays within about this much of an incidence limit flicker. At 1.5 deg the labels were so
    # random that no classifier of the pose could exceed 45% whole-scan accuracy (label_ceiling),
    # below the 61% the paper's smallest classifier reached on the real scans; at 0.3 the
    # ceiling is 77% and the other statistics still match (docs/f1tenth.md, section 1).
    softness_deg: float = 0.3
    sigma: float = 0.012
    sigma_per_m: float = 0.008
    mixed_pixel_jump: float = 0.25
    outlier_rate: float = 0.04
    dropout_rate: float = 0.003
    steering_lag: float = 0.05
    track: Track = field(default_factory=world.square)

    def covered(self) -> "RealWorld":
        return RealWorld(**{**self._fields(), "panels": tuple(p for p in self.panels if p.fixed)})

    def _fields(self) -> dict:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    def describe(self) -> dict:
        out = {k: v for k, v in self._fields().items() if k not in ("track", "panels")}
        out["panels"] = [asdict(p) for p in self.panels]
        return out

    @classmethod
    def from_description(cls, description: dict) -> "RealWorld":
        """The world of ``describe()`` (as recorded in a runs file's meta) on the square loop."""
        fields = dict(description)
        try:
            fields["panels"] = tuple(Panel(**p) for p in fields.get("panels", ()))
            if isinstance(fields.get("gloss_deg"), list):
                fields["gloss_deg"] = tuple(fields["gloss_deg"])
            return cls(**fields)
        except TypeError as error:
            raise InputError(
                f"not a measurement-simulator world description ({error}): "
                "it is the 'world' entry of the meta of runs written by percver cases f1tenth simulate"
            ) from None

    def scan(self, states, rng, lidar=None) -> np.ndarray:
        """Raw scans (N x 1081, or the rays of ``lidar``) from poses (N x >=3)."""
        lidar = lidar or world.scanner()
        states = np.atleast_2d(states)
        hits = lidar.cast(self.track, states[:, 0], states[:, 1], states[:, 2])
        true = hits.range
        incidence = np.degrees(np.arccos(np.clip(np.nan_to_num(hits.cos_incidence, nan=1.0), 0.0, 1.0)))
        where = hits.wall_coordinate(self.track)
        gloss = np.broadcast_to(np.asarray(self.gloss_deg, dtype=float), (len(self.track.segments),))
        # Every ray is lost with a probability rising smoothly across its wall's limit(s).
        above = np.where(hits.segment >= 0, gloss[np.maximum(hits.segment, 0)], 90.0)
        below = np.full(true.shape, -90.0)
        saturates = np.zeros(true.shape, dtype=bool)
        with np.errstate(invalid="ignore"):
            for panel in self.panels:
                on = (where >= panel.start) & (where <= panel.end)
                if panel.material == "glass":
                    below = np.where(on, np.maximum(below, panel.threshold_deg), below)
                else:
                    above = np.where(on, np.minimum(above, panel.threshold_deg), above)
                saturates |= on & (panel.echo == "max")
        soft = self.softness_deg
        # Logistic edges as 0.5 (1 + tanh(x / 2)): no overflow far from an edge.
        lost_probability = 0.5 * (2.0 + np.tanh((incidence - above) / (2 * soft)) - np.tanh((incidence - below) / (2 * soft)))
        mirrored = rng.random(true.shape) < lost_probability

        sigma = self.sigma + self.sigma_per_m * np.minimum(true, lidar.max_range)
        reading = true + rng.normal(0.0, 1.0, true.shape) * sigma
        # Mixed pixels: a beam straddling a depth edge averages both sides.
        jump = np.abs(np.diff(np.minimum(true, lidar.max_range), axis=1)) > self.mixed_pixel_jump
        edge = np.zeros(true.shape, dtype=bool)
        edge[:, :-1] |= jump
        edge[:, 1:] |= jump
        neighbour = np.minimum(np.roll(true, 1, axis=1), np.roll(true, -1, axis=1))
        blend = rng.random(true.shape)
        reading = np.where(edge & (rng.random(true.shape) < 0.5), blend * true + (1 - blend) * neighbour, reading)
        outlier = rng.random(true.shape) < self.outlier_rate
        reading = np.where(outlier, rng.uniform(0.05, 1.0, true.shape) * np.minimum(true, lidar.max_range), reading)

        reading = np.round(np.clip(reading, 0.0, None), 3)
        reading = np.where(reading >= lidar.max_range, lidar.max_range, reading)
        reading = np.where(mirrored, np.where(saturates, lidar.max_range, 0.0), reading)
        reading = np.where(rng.random(true.shape) < self.dropout_rate, 0.0, reading)
        return reading


def label_ceiling(real: RealWorld, poses, threshold: float, *, draws: int = 10, seed: int = 0) -> dict:
    """The whole-scan accuracy that no classifier of the pose can beat on this world's labels.

    A ray's label (|21-ray reading - canonical| > ``threshold``) is random for a given pose:
    noise, lost echoes, rays flickering at a surface's incidence limit. With ``draws``
    independent scans per pose, p_i is the share of draws labelling ray i; the best decision
    per ray is the likelier label, right with probability max(p_i, 1 - p_i), and a whole scan is
    right with their product. ``ceiling`` is its mean over ``poses`` (N x 3), ``certain`` the
    share of poses whose 21 labels agree in every draw. Diagnostic: it needs the hidden world.
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))[:, :3]
    if draws < 2:
        raise InputError(f"label_ceiling needs at least 2 draws per pose, got {draws}")
    canonical = world.controller_lidar().scan(real.track, poses)
    rng = np.random.default_rng(seed)
    share = np.zeros(canonical.shape)
    for _ in range(draws):
        share += np.abs(world.controller_view(real.scan(poses, rng)) - canonical) > threshold
    p = share / draws
    likelier = np.maximum(p, 1.0 - p)
    return {
        "threshold": float(threshold),
        "draws": int(draws),
        "poses": len(poses),
        "ceiling": float(np.prod(likelier, axis=1).mean()),
        "certain": float(np.mean(np.all(likelier == 1.0, axis=1))),
        "ray_error": float(np.mean(1.0 - likelier)),
    }


def paper_run_counts(data=None) -> dict:
    """Runs per controller of the real data (9 or 10 each, 116 in all)."""
    crashes = real_statistics(data).crashes
    return {name: len(crashes[ctl.short_name(name)]) for name in ctl.NAMES}


def simulate(
    runs_per_controller: int | dict = 10,
    *,
    names=None,
    world_model: RealWorld | None = None,
    start: loop.StartBox | None = None,
    seed: int = 0,
    data=None,
    controllers: dict | None = None,
) -> loop.Runs:
    """Drive ``runs_per_controller`` runs (a count, or ``{name: count}`` such as
    ``paper_run_counts()``) of each controller (default all 12) through the first turn of the
    "real" world, recording raw 40 Hz scans, the steering and the true states."""
    if isinstance(runs_per_controller, dict):
        counts = {name: int(runs_per_controller[name]) for name in (names or runs_per_controller)}
    else:
        counts = {name: int(runs_per_controller) for name in (names or ctl.NAMES)}
    bad = {name: count for name, count in counts.items() if count < 1}
    if bad:
        raise InputError(f"every controller needs at least one run, got {bad}")
    real = world_model or RealWorld()
    loaded = controllers or ctl.load_all(list(counts), data)
    rng = np.random.default_rng(seed)
    order = [name for name, count in counts.items() for _ in range(count)]
    starts = (start or loop.StartBox()).sample(len(order), rng)

    def sense(states, rng):
        raw = real.scan(states, rng)
        return raw, world.controller_view(raw)

    runs = loop.drive(
        starts, [loaded[name] for name in order], sense, rate=40.0, track=real.track, seed=seed + 1, steering_lag=real.steering_lag
    )
    runs.meta = {"world": real.describe(), "seed": seed, "start": asdict(start or loop.StartBox())}
    return runs


def to_measurements(runs: loop.Runs) -> Measurements:
    """Runs as ``Measurements``: raw scans, steering controls, run ids and times; the true states
    (x, y, theta, v) fill the format's ``states`` but the modelling pipeline never reads them.
    Per-run controller names and crash labels travel in ``meta["runs"]``."""
    meta = dict(runs.meta)
    meta["rate_hz"] = runs.rate
    meta["runs"] = [
        {"id": i, "controller": name, "outcome": outcome, "crashed": outcome == "crash"}
        for i, (name, outcome) in enumerate(zip(runs.controllers, runs.outcomes))
    ]
    return Measurements(
        runs.states,
        runs.scans,
        controls=runs.controls[:, None],
        trajectory=runs.run,
        time=runs.time,
        state_names=("x", "y", "theta", "v"),
        measurement_names=world.scanner(),
        control_names=("steering",),
        meta=meta,
    )


def from_measurements(data: Measurements) -> loop.Runs:
    """The inverse of ``to_measurements`` (for files written by ``percver cases f1tenth simulate``)."""
    runs = data.meta.get("runs")
    if not runs or data.trajectory is None or data.controls is None:
        raise InputError(
            f"{data.source or 'the measurements'} are not F1/10 runs: they need meta['runs'], 'trajectory' and "
            "'controls' as written by percver cases f1tenth simulate"
        )
    if data.measurements is None or data.measurements.shape[1] != 1081:
        raise InputError(f"{data.source or 'the measurements'}: F1/10 runs hold raw 1081-ray scans")
    return loop.Runs(
        run=data.trajectory,
        time=data.time,
        states=data.states,
        scans=data.measurements,
        controls=data.controls[:, 0],
        controllers=[r["controller"] for r in runs],
        outcomes=[r["outcome"] for r in runs],
        rate=float(data.meta.get("rate_hz", 40.0)),
        meta={k: v for k, v in data.meta.items() if k not in ("runs", "rate_hz")},
    )


def reflected_rays(view, canonical, limit: float = world.CONTROLLER_RANGE) -> np.ndarray:
    """Rays that read the range limit although the canonical model sees a wall within range."""
    return (view >= limit) & (canonical < limit * 0.98)


def _output_summary(values) -> dict:
    return {
        "mean": float(values.mean()),
        "std": float(values.std()),
        "saturated": float(np.mean(np.abs(values) > 0.9)),
        "left": float(np.mean(values > 0.5)),
        "right": float(np.mean(values < -0.5)),
    }


def calibration(runs: loop.Runs, poses=None, stats=None, controllers: dict | None = None) -> dict:
    """The simulated runs' statistics next to the real ones.

    ``poses`` (N x 3) are the poses at which the canonical scans are taken (default the true
    states; pass the particle filter's estimates for the comparison the real figures made).
    With ``stats`` and ``controllers`` (``{name: Controller}`` for the 12), every controller's
    raw outputs on every simulated scan are compared with its outputs on the real scans
    (``ControllerOuputsOnRealData.npy``): summary statistics and the Wasserstein distance.
    """
    view = world.controller_view(runs.scans)
    poses = runs.states[:, :3] if poses is None else poses
    canonical = world.controller_lidar().scan(world.square(), poses)
    lost = reflected_rays(view, canonical)
    # Like the real figures: every ray that is not reflected counts, those at the limit in both too.
    errors = np.abs(view - canonical)[~lost]
    out = {
        "runs": len(runs.outcomes),
        "scans": len(runs.run),
        "scans_per_run": len(runs.run) / len(runs.outcomes),
        "crashes": int(runs.crashed.sum()),
        "reflected_per_scan": float(lost.sum(axis=1).mean()),
        "reflected_histogram": np.bincount(lost.sum(axis=1), minlength=8)[:8].tolist(),
        "mean_error_m": float(errors.mean()),
        "within_5cm": float(np.mean(errors <= 0.05)),
    }
    if stats is not None:
        out["real"] = stats.summary()
        out["real"]["scans_per_run"] = stats.outputs.shape[1] / stats.runs
        if controllers is not None:
            from scipy.stats import wasserstein_distance

            # Yardsticks: noise-free canonical scans at the true poses, and how far the real
            # outputs' first half of scans lies from their second half.
            truth = world.controller_lidar().scan(world.square(), runs.states[:, :3])
            outputs = {}
            for row, name in enumerate(ctl.NAMES):
                if name in controllers:
                    sim, real = controllers[name].raw(view), stats.outputs[row]
                    half = len(real) // 2
                    outputs[name] = {
                        "sim": _output_summary(sim),
                        "real": _output_summary(real),
                        "wasserstein": float(wasserstein_distance(sim, real)),
                        "wasserstein_canonical": float(wasserstein_distance(controllers[name].raw(truth), real)),
                        "wasserstein_real_halves": float(wasserstein_distance(real[:half], real[half:])),
                    }
            out["controller_outputs"] = outputs
    return out
