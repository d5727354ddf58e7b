"""Pose estimation for labelling runs without ground truth (not the estimator h_e of the loop): a
particle filter (Thrun et al., ch. 4 and 6).

Motion: the bicycle model (``dynamics``) driven by the logged steering, with process noise.
Measurement: a beam model on a subset of the raw 1081 rays, each echo a mixture of a Gaussian
around the canonical range and a uniform clutter term; rays without an echo do not count, so
that rays swallowed by reflective surfaces do not pull the estimate. Down a long hallway the
position along it is unobservable until the front wall is in range; the filter keeps particles
spread along the heading so that it locks on once it is. Runs are filtered side by
side (one particle set each), one scan index at a time, so numpy casts all particles of all
runs at once.

Only scans, controls, run ids and times are read; the true states are never an input.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from percver.cases.f1tenth import dynamics, loop, world
from percver.errors import InputError
from percver.sensors.lidar import Lidar


@dataclass(frozen=True)
class FilterSettings:
    """Particle filter parameters (metres, radians, seconds)."""

    particles: int = 300
    ray_step: int = 18  # every 18th of the 1081 rays: 61 rays, 4.5 degrees apart
    # ... and every 3rd within this many degrees of ahead: far down a hallway only rays close to
    # ahead reach the front wall, the one thing that tells positions along the hallway apart.
    ahead_deg: float = 15.0
    ahead_step: int = 3
    hit_sigma: float = 0.05
    p_hit: float = 0.95
    p_clutter: float = 0.05
    p_lost: float = 1.0  # glass doors swallow exactly the rays that would see the front wall
    temperature: float = 4.0  # rays are not independent: soften the joint likelihood
    position_noise: float = 0.05  # per sqrt(second)
    heading_noise: float = 0.05
    speed_noise: float = 0.3
    # Along a hallway whose end is out of range nothing tells positions apart, and resampling on
    # the well-observed directions would collapse that one at random; after each resampling this
    # share of particles slides along its heading, so the right position survives until seen.
    slide_share: float = 0.2
    slide_sigma: float = 1.0
    # Where runs start (wider than the simulator's start box: the filter does not know it).
    start: loop.StartBox = loop.StartBox(y1=(0.3, 1.2), y2=(8.0, 12.0), y4_deg=(-10.0, 10.0))


@dataclass(frozen=True)
class PoseEstimate:
    """Estimated poses (N x 3: x, y, theta) and speeds (N,) row-aligned with the scans, and the
    particles' position spread (N,) in metres."""

    poses: np.ndarray
    speed: np.ndarray
    spread: np.ndarray

    def errors(self, true_states) -> dict:
        """Position (m) and heading (deg) errors against ground truth (N x >=3)."""
        true_states = np.atleast_2d(true_states)
        position = np.hypot(*(self.poses[:, :2] - true_states[:, :2]).T)
        heading = np.degrees(np.abs((self.poses[:, 2] - true_states[:, 2] + np.pi) % (2 * np.pi) - np.pi))
        return {
            "position_mean_m": float(position.mean()),
            "position_median_m": float(np.median(position)),
            "position_p95_m": float(np.percentile(position, 95)),
            "heading_mean_deg": float(heading.mean()),
            "heading_p95_deg": float(np.percentile(heading, 95)),
        }


def _log_likelihood(measured, predicted, settings: FilterSettings, limit: float) -> np.ndarray:
    """Sum over rays of log p(reading | canonical range), (..., K) -> (...).

    A ray without an echo where the model sees a wall has likelihood ``p_lost`` (default 1: no
    weight at all): reflective walls and glass swallow such rays, and scoring them would drag
    the particles to poses where the model sees nothing either."""
    echoed = (measured > world.NO_ECHO) & (measured < limit)
    in_range = predicted < limit * 0.99
    gauss = np.exp(-0.5 * ((measured - predicted) / settings.hit_sigma) ** 2) / (np.sqrt(2 * np.pi) * settings.hit_sigma)
    echo = np.where(in_range, settings.p_hit * gauss, 0.0) + settings.p_clutter / limit
    silent = np.where(in_range, settings.p_lost, 1.0)
    return np.log(np.where(echoed, echo, silent)).sum(axis=-1) / settings.temperature


def _systematic(weights, rng) -> np.ndarray:
    """Indices resampled systematically, per row of ``weights`` (R x P, rows sum to 1)."""
    r, p = weights.shape
    positions = (rng.random((r, 1)) + np.arange(p)[None, :]) / p
    cumulative = np.cumsum(weights, axis=1)
    cumulative[:, -1] = 1.0
    return np.stack([np.searchsorted(cumulative[i], positions[i]) for i in range(r)])


def estimate_poses(
    scans, controls, trajectory, time, *, settings: FilterSettings | None = None, seed: int = 0, track=None, progress: bool = False
) -> PoseEstimate:
    """Estimate (x, y, theta) for every raw scan (N x 1081) of the runs ``trajectory`` (N,),
    sorted by (run, ``time``), with the steering ``controls`` (N,) in effect after each scan."""
    settings = settings or FilterSettings()
    scans = np.atleast_2d(np.asarray(scans, dtype=float))
    controls = np.asarray(controls, dtype=float).reshape(-1)
    trajectory = np.asarray(trajectory)
    time = np.asarray(time, dtype=float)
    n = len(scans)
    if scans.shape[1] != 1081 or not (len(controls) == len(trajectory) == len(time) == n):
        raise InputError(
            f"estimate_poses needs raw 1081-ray scans with one control, run id and time per scan; got scans "
            f"{scans.shape}, controls {controls.shape}, trajectory {trajectory.shape}, time {time.shape}"
        )
    track = track or world.square()
    rng = np.random.default_rng(seed)
    full = world.scanner()
    ahead = np.flatnonzero(np.abs(full.angles_deg) <= settings.ahead_deg)[:: settings.ahead_step]
    index = np.union1d(np.arange(0, 1081, settings.ray_step), ahead)
    lidar = Lidar(full.angles_deg[index], full.max_range)
    runs = list(dict.fromkeys(trajectory.tolist()))
    rows = [np.flatnonzero(trajectory == r) for r in runs]
    longest = max(len(r) for r in rows)
    p = settings.particles
    particles = np.stack([settings.start.sample(p, rng) for _ in runs])  # R x P x 4
    weights = np.full((len(runs), p), 1.0 / p)
    poses = np.empty((n, 3))
    speed = np.empty(n)
    spread = np.empty(n)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n, desc="particle filter", unit="scan")
    for k in range(longest):
        live = [i for i, r in enumerate(rows) if len(r) > k]
        here = np.array([rows[i][k] for i in live])
        group = particles[live]
        if k > 0:
            before = np.array([rows[i][k - 1] for i in live])
            dt = time[here] - time[before]
            flat = group.reshape(-1, 4)
            moved = np.empty_like(flat)
            # Runs share a scan period almost always; integrate each distinct period once.
            step = np.repeat(dt, p)
            steer = np.repeat(controls[before], p)
            for value in np.unique(step):
                sel = step == value
                moved[sel] = dynamics.integrate(flat[sel], steer[sel], float(value))
            root = np.sqrt(step)[:, None]
            noise = (
                rng.normal(size=moved.shape)
                * root
                * np.array([settings.position_noise, settings.position_noise, settings.heading_noise, settings.speed_noise])
            )
            moved += noise
            moved[:, 3] = np.maximum(moved[:, 3], 0.0)
            group = moved.reshape(len(live), p, 4)
        flat = group.reshape(-1, 4)
        predicted = np.minimum(lidar.ranges(track, flat[:, 0], flat[:, 1], flat[:, 2]), lidar.max_range)
        log_l = _log_likelihood(scans[here][:, index][:, None, :], predicted.reshape(len(live), p, -1), settings, lidar.max_range)
        log_w = np.log(weights[live]) + log_l
        log_w -= log_w.max(axis=1, keepdims=True)
        w = np.exp(log_w)
        w /= w.sum(axis=1, keepdims=True)
        mean_xy = np.einsum("rp,rpk->rk", w, group[:, :, :2])
        heading = np.arctan2(np.einsum("rp,rp->r", w, np.sin(group[:, :, 2])), np.einsum("rp,rp->r", w, np.cos(group[:, :, 2])))
        poses[here] = np.column_stack([mean_xy, heading])
        speed[here] = np.einsum("rp,rp->r", w, group[:, :, 3])
        spread[here] = np.sqrt(np.einsum("rp,rpk->r", w, (group[:, :, :2] - mean_xy[:, None, :]) ** 2))
        effective = 1.0 / (w**2).sum(axis=1)
        resample = effective < p / 2
        if resample.any():
            picks = _systematic(w[resample], rng)
            chosen = np.take_along_axis(group[resample], picks[:, :, None], axis=1)
            slide = (rng.random(chosen.shape[:2]) < settings.slide_share) * rng.normal(0.0, settings.slide_sigma, chosen.shape[:2])
            chosen[:, :, 0] += slide * np.cos(chosen[:, :, 2])
            chosen[:, :, 1] += slide * np.sin(chosen[:, :, 2])
            group[resample] = chosen
            w[resample] = 1.0 / p
        particles[live] = group
        weights[live] = w
        if bar is not None:
            bar.update(len(live))
    if bar is not None:
        bar.close()
    return PoseEstimate(poses, speed, spread)
