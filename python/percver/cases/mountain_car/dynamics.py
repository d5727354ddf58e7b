"""Mountain Car dynamics, reward and property (paper, Appendix A: "Dynamics", "Verification"), and the rows of Table 1.

The plant is written once as percver expressions: :func:`simulate` evaluates them on float
batches, and verification will evaluate the same expressions on Taylor models.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from percver.errors import InputError

P_MIN, P_MAX = -1.2, 0.6
V_MAX = 0.07
POWER = 0.0015
GRAVITY = 0.0025
GOAL = 0.45
STEPS = 150
GOAL_REWARD = 100.0
CONTROL_COST = 0.1
REWARD_BOUND = 90.0

CONTRAST_RANGE = (0.3, 2.0)
BLUR_RANGE = (0.0, 0.3)

# The rows of the paper's Table 1: initial positions (v0 = 0) and noise ranges. "canonical" is the
# noise-free chain (the appendix figure of the canonical model), evaluated over the paper's initial set p0 in [-0.6, -0.4].
ROWS = {
    "canonical": {"p0": (-0.6, -0.4)},
    "contrast": {"p0": (-0.59, -0.4), "delta_c": CONTRAST_RANGE},
    "blur": {"p0": (-0.59, -0.4), "delta_b": BLUR_RANGE},
    "composite": {"p0": (-0.55, -0.4), "delta_c": (0.5, 2.0), "delta_b": (0.0, 0.15)},
}
NOISES = tuple(ROWS)


def noise_row(noise: str) -> dict:
    """The initial set and noise ranges of one row (``canonical``, ``contrast``, ``blur``, ``composite``)."""
    if noise not in ROWS:
        raise InputError(f"unknown Mountain Car noise '{noise}'; choose one of {list(ROWS)}")
    return dict(ROWS[noise])


def equations() -> dict:
    """One step ``{"p": p', "v": v'}`` as expressions of ``p``, ``v`` and the thrust ``u``.

    ``v' = clip(v + 0.0015 u - 0.0025 cos(3 p), -0.07, 0.07)``, ``p' = p + v'``; a car that reaches
    the left wall (``p' <= -1.2``) stops there, as in gymnasium and Verisig's model.
    """
    import percver as pv

    p, v, u = pv.variables("p v u")
    v_next = pv.clip(v + POWER * u - GRAVITY * pv.cos(3 * p), -V_MAX, V_MAX)
    p_next = p + v_next
    at_wall = p_next <= P_MIN
    return {"p": pv.where(at_wall, P_MIN, p_next), "v": pv.where(at_wall, 0.0, v_next)}


_STEP = None


def step(p, v, u) -> tuple[np.ndarray, np.ndarray]:
    """The next (p, v) of float batches, evaluated from :func:`equations`."""
    global _STEP
    import percver as pv

    if _STEP is None:
        eq = equations()
        _STEP = [eq["p"], eq["v"]]
    p, v, u = np.broadcast_arrays(*(np.asarray(x, dtype=float).ravel() for x in (p, v, u)))
    out = pv.evaluate(_STEP, {"p": p, "v": v, "u": u})
    return out[:, 0], out[:, 1]


@dataclass(frozen=True)
class Trajectories:
    """Closed-loop runs. ``p``, ``v``: (n, steps + 1); ``u``: (n, steps); entries after a run reached the
    goal repeat its last state (``u`` = 0); ``reached_at``: the step count at which p >= 0.45 (-1: never)."""

    p: np.ndarray
    v: np.ndarray
    u: np.ndarray
    reached_at: np.ndarray

    @property
    def active(self) -> np.ndarray:
        """(n, steps) mask of the steps each run actually took (before reaching the goal)."""
        k = np.arange(self.u.shape[1])[None, :]
        end = np.where(self.reached_at >= 0, self.reached_at, self.u.shape[1])
        return k < end[:, None]

    @property
    def reward(self) -> np.ndarray:
        """-0.1 u^2 per step taken, +100 on reaching the goal (Appendix A, "Verification")."""
        cost = CONTROL_COST * np.sum(np.where(self.active, self.u**2, 0.0), axis=1)
        return np.where(self.reached_at >= 0, GOAL_REWARD, 0.0) - cost

    @property
    def safe(self) -> np.ndarray:
        """The property: goal reached within the horizon with reward above 90."""
        return (self.reached_at >= 0) & (self.reward > REWARD_BOUND)


def simulate(p0, controller: Callable, *, v0=0.0, steps: int = STEPS, on_step: Callable | None = None) -> Trajectories:
    """Run ``controller(k, p, v, active) -> u`` (batched; ``active`` marks runs not yet at the goal) from ``p0``.

    The controller sees every run at every step (so it can evaluate batches of fixed size); thrust
    is clipped to [-1, 1] and ignored for runs that have reached the goal.
    """
    p0 = np.atleast_1d(np.asarray(p0, dtype=float))
    if p0.ndim != 1 or not np.all(np.isfinite(p0)):
        raise InputError(f"p0 must be a finite number or 1-D array of initial positions, got shape {p0.shape}")
    n = len(p0)
    p = np.empty((n, steps + 1))
    v = np.empty((n, steps + 1))
    u = np.zeros((n, steps))
    p[:, 0] = p0
    v[:, 0] = np.broadcast_to(np.asarray(v0, dtype=float), (n,))
    reached_at = np.where(p0 >= GOAL, 0, -1)
    for k in range(steps):
        active = reached_at < 0
        if not active.any():
            p[:, k + 1 :], v[:, k + 1 :] = p[:, k : k + 1], v[:, k : k + 1]
            break
        thrust = np.clip(np.asarray(controller(k, p[:, k], v[:, k], active), dtype=float).reshape(n), -1.0, 1.0)
        u[:, k] = np.where(active, thrust, 0.0)
        p_next, v_next = step(p[:, k], v[:, k], u[:, k])
        p[:, k + 1] = np.where(active, p_next, p[:, k])
        v[:, k + 1] = np.where(active, v_next, v[:, k])
        reached_at = np.where(active & (p[:, k + 1] >= GOAL), k + 1, reached_at)
        if on_step is not None:
            on_step(k)
    return Trajectories(p, v, u, reached_at)
