"""Driving runs through the first right turn: the closed loop shared by the "real" measurement
simulator and the simulations with a noise model (the trajectory-based metric).

A run starts at rest in the first hallway, reads a scan at every tick (40 Hz on the real car,
10 Hz in model simulations), lets its controller pick a new steering angle every 0.1 s from
the latest scan, and ends when the car comes within ``CRASH_MARGIN`` of a wall (a crash), gets
2.5 m from the first hallway's left wall into the second hallway (done, as in the
verification model), or after ``periods`` control periods (timeout).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from percver.cases.f1tenth import dynamics, world
from percver.errors import InputError

CRASH_MARGIN = 0.15
DONE_Y1 = 2.5
PERIODS = 70


@dataclass(frozen=True)
class StartBox:
    """Random starts at rest, in first-hallway coordinates (the verification model starts at
    y1 in [0.65, 0.85], y2 = 9, y4 = 0)."""

    y1: tuple = (0.55, 0.95)
    y2: tuple = (9.0, 11.0)
    y4_deg: tuple = (-5.0, 5.0)

    def sample(self, n: int, rng) -> np.ndarray:
        """``n`` world states (x, y, theta, v = 0)."""
        local = np.column_stack([rng.uniform(*self.y1, n), rng.uniform(*self.y2, n), np.radians(rng.uniform(*self.y4_deg, n))])
        return np.column_stack([world.from_local(local), np.zeros(n)])


@dataclass
class Runs:
    """Driven runs, row-aligned per tick: ``run``, ``time``, true ``states`` (N x 4), the
    recorded ``scans`` (N x m), the steering ``controls`` (N,) in effect after each scan; per
    run: ``controllers`` (names), ``outcomes`` ("crash" | "done" | "timeout")."""

    run: np.ndarray
    time: np.ndarray
    states: np.ndarray
    scans: np.ndarray
    controls: np.ndarray
    controllers: list
    outcomes: list
    rate: float
    meta: dict = field(default_factory=dict)

    @property
    def crashed(self) -> np.ndarray:
        return np.array([o == "crash" for o in self.outcomes])

    def rows(self, run: int) -> np.ndarray:
        return np.flatnonzero(self.run == run)

    def safe_share(self) -> dict:
        """Percentage of runs without a crash, per controller name."""
        out = {}
        for name in dict.fromkeys(self.controllers):
            flags = [o != "crash" for c, o in zip(self.controllers, self.outcomes) if c == name]
            out[name] = 100.0 * float(np.mean(flags))
        return out


def drive(
    starts, controllers, sense, *, rate: float = 10.0, periods: int = PERIODS, track=None, seed=None, steering_lag: float = 0.0
) -> Runs:
    """Drive one run per row of ``starts`` (R x 4 world states) with ``controllers`` (R
    ``Controller`` objects, one per run; runs sharing a controller are evaluated together).

    ``sense(states, rng) -> (recorded, ranges21)`` gives what is stored for each scan and the
    21 ranges (m) the controller reads. ``rate`` scans per second, a multiple of 10 Hz.
    ``steering_lag`` > 0 is the time constant (s) of a servo that follows the commanded
    steering to first order, updated once per scan tick (the canonical car has none); the
    recorded controls are the commands.
    """
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if len(controllers) != len(starts):
        raise InputError(f"{len(starts)} starts but {len(controllers)} controllers: give one controller per run")
    ticks_per_period = int(round(rate * dynamics.PERIOD))
    if ticks_per_period < 1 or abs(ticks_per_period - rate * dynamics.PERIOD) > 1e-9:
        raise InputError(f"rate {rate} Hz is not a multiple of the 10 Hz control rate")
    track = track or world.square()
    rng = np.random.default_rng(seed)
    n = len(starts)
    states = starts.copy()
    steering = np.zeros(n)
    applied = np.zeros(n)
    follow = 1.0 - np.exp(-1.0 / (rate * steering_lag)) if steering_lag > 0 else 1.0
    active = np.ones(n, dtype=bool)
    outcomes = ["timeout"] * n
    groups = {}
    for i, controller in enumerate(controllers):
        groups.setdefault(id(controller), (controller, []))[1].append(i)
    log = {key: [] for key in ("run", "time", "states", "scans", "controls")}
    for tick in range(periods * ticks_per_period + 1):
        index = np.flatnonzero(active)
        if index.size == 0:
            break
        recorded, ranges = sense(states[index], rng)
        if tick % ticks_per_period == 0:
            position = {run: k for k, run in enumerate(index)}
            for controller, members in groups.values():
                rows = [position[m] for m in members if active[m]]
                if rows:
                    steering[index[rows]] = controller(ranges[rows])
        for key, value in (
            ("run", index),
            ("time", np.full(index.size, tick / rate)),
            ("states", states[index]),
            ("scans", recorded),
            ("controls", steering[index]),
        ):
            log[key].append(value)
        crashed = world.wall_distance(track, states[index]) < CRASH_MARGIN
        done = world.to_local(states[index])[:, 0] >= DONE_Y1
        for k in np.flatnonzero(crashed | done):
            outcomes[index[k]] = "crash" if crashed[k] else "done"
        active[index[crashed | done]] = False
        moving = np.flatnonzero(active)
        applied += follow * (steering - applied)
        states[moving] = dynamics.integrate(states[moving], applied[moving], 1.0 / rate)
    arrays = {key: np.concatenate(value) for key, value in log.items()}
    order = np.lexsort((arrays["time"], arrays["run"]))
    return Runs(
        run=arrays["run"][order],
        time=arrays["time"][order],
        states=arrays["states"][order],
        scans=arrays["scans"][order],
        controls=arrays["controls"][order],
        controllers=[c.name for c in controllers],
        outcomes=outcomes,
        rate=rate,
    )
