"""Generators of "real" data with hidden effects, written independently of percver.

The LiDAR world here is the F1/10 square loop (outer walls [0, 20]^2, inner [1.5, 18.5]^2,
driven clockwise) cast by axis-aligned slab intersection rather than percver's segment
solver; images use PIL's ImageEnhance; dynamics are Mountain Car written out by hand. The
tests know the hidden effects; percver has to find them.
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageEnhance

L, W = 20.0, 1.5
ANGLES = np.radians(np.arange(-115.0, 115.0 + 1e-9, 11.5))
# (axis, coordinate, lo, hi): axis 0 = wall at x = coordinate spanning y in [lo, hi]; axis 1 the reverse.
WALLS = [
    (0, 0.0, 0.0, L),
    (0, L, 0.0, L),
    (1, 0.0, 0.0, L),
    (1, L, 0.0, L),
    (0, W, W, L - W),
    (0, L - W, W, L - W),
    (1, W, W, L - W),
    (1, L - W, W, L - W),
]
NORTH_OUTER = 3


def poses(n, seed, margin=0.3, spread_deg=25.0):
    """Poses in the ring between the squares, heading clockwise along the loop."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        x, y = rng.uniform(margin, L - margin, 2)
        if min(x, y, L - x, L - y) > W - margin:  # not in the ring (or too close to the inner wall)
            continue
        # clockwise direction of travel: west side north, north side east, east side south, south side west
        side = int(np.argmin([x, L - y, L - x, y]))
        heading = [np.pi / 2, 0.0, -np.pi / 2, np.pi][side]
        out.append((x, y, heading + np.radians(rng.uniform(-spread_deg, spread_deg))))
    return np.array(out)


def _cast(px, py, angle):
    """Distance to the nearest wall and, for it, (wall index, position along it, cosine of incidence)."""
    dx, dy = np.cos(angle), np.sin(angle)
    best = np.full(angle.shape, np.inf)
    wall = np.full(angle.shape, -1)
    where = np.full(angle.shape, np.nan)
    cos_inc = np.full(angle.shape, np.nan)
    for index, (a, c, lo, hi) in enumerate(WALLS):
        along, across = (dx, dy) if a == 0 else (dy, dx)
        start, other = (px, py) if a == 0 else (py, px)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (c - start) / along
        hit_at = other + t * across
        ok = (t > 1e-12) & (hit_at >= lo) & (hit_at <= hi) & (t < best)
        best = np.where(ok, t, best)
        wall = np.where(ok, index, wall)
        where = np.where(ok, hit_at, where)
        cos_inc = np.where(ok, np.abs(along), cos_inc)
    return best, wall, where, cos_inc


def scan(
    states,
    *,
    seed=0,
    yaw_deg=0.0,
    forward=0.0,
    left=0.0,
    bias=0.0,
    scale=1.0,
    panel=None,
    ghost=None,
    dropout=0.0,
    dropout_far=None,
    dropout_grazing=None,
    noise=0.01,
    max_range=5.0,
):
    """21-ray scans with hidden effects.

    ``panel`` = (x_lo, x_hi, threshold_deg): a reflective stretch of the north outer wall
    (y = 20) where rays beyond the threshold incidence return nothing. ``ghost`` = (cx, cy, r):
    a round obstacle the canonical model does not know. ``dropout_far`` = (near, far, rate): echoes
    are lost with a probability rising linearly from 0 at ``near`` metres to ``rate`` at ``far``.
    ``dropout_grazing`` = (threshold_deg, rate): echoes hitting a wall beyond the threshold
    incidence are lost with probability ``rate``.
    """
    rng = np.random.default_rng(seed)
    x, y, th = states[:, 0:1], states[:, 1:2], states[:, 2:3]
    sx = x + forward * np.cos(th) - left * np.sin(th)
    sy = y + forward * np.sin(th) + left * np.cos(th)
    angle = th + np.radians(yaw_deg) + ANGLES[None, :]
    sx, sy = np.broadcast_to(sx, angle.shape), np.broadcast_to(sy, angle.shape)
    r, wall, where, cos_inc = _cast(sx, sy, angle)
    if panel is not None:
        lo, hi, threshold = panel
        on_panel = (wall == NORTH_OUTER) & (where >= lo) & (where <= hi)
        grazing = np.degrees(np.arccos(np.clip(cos_inc, 0, 1))) > threshold
        r = np.where(on_panel & grazing, np.inf, r)
    if ghost is not None:
        cx, cy, radius = ghost
        ox, oy = sx - cx, sy - cy
        b = ox * np.cos(angle) + oy * np.sin(angle)
        disc = b**2 - (ox**2 + oy**2 - radius**2)
        t = -b - np.sqrt(np.maximum(disc, 0))
        r = np.where((disc > 0) & (t > 0) & (t < r), t, r)
    echo = np.isfinite(r) & (r < max_range)
    r = np.where(echo, scale * r + bias + rng.normal(0, noise, r.shape), max_range)
    lost = rng.random(r.shape) < dropout
    if dropout_far is not None:
        near, far, rate = dropout_far
        lost |= echo & (rng.random(r.shape) < rate * np.clip((r - near) / (far - near), 0.0, 1.0))
    if dropout_grazing is not None:
        threshold, rate = dropout_grazing
        grazing = np.degrees(np.arccos(np.clip(np.nan_to_num(cos_inc, nan=1.0), 0, 1))) > threshold
        lost |= echo & grazing & (rng.random(r.shape) < rate)
    r = np.where(lost, max_range, r)
    return np.clip(r, 0.0, max_range)


# ---------------------------------------------------------------- images
H, WIDTH = 20, 30


def render(states):
    """A 20 x 30 picture of a car (bright blob) on a hill (dim curve) at position p = states[:, 0]."""
    p = np.asarray(states, dtype=float)[:, 0]
    rows, cols = np.mgrid[0:H, 0:WIDTH]
    col = (p + 1.2) / 1.8 * (WIDTH - 5) + 2
    row = 10 - 6 * np.sin(3 * p)
    blob = np.exp(-((rows[None] - row[:, None, None]) ** 2 + (cols[None] - col[:, None, None]) ** 2) / (2 * 1.5**2))
    hill_row = 10 - 6 * np.sin(3 * (cols / (WIDTH - 5) * 1.8 - 1.2)) + 2
    hill = 0.3 * np.exp(-((rows - hill_row) ** 2) / 0.8)
    return np.clip(np.maximum(blob, hill[None]), 0, 1)


def _pil_contrast(image, factor):
    grey = Image.fromarray(np.round(image * 255).astype(np.uint8), mode="L")
    return np.asarray(ImageEnhance.Contrast(grey).enhance(factor), dtype=float) / 255.0


def blurred(look, states, delta):
    """The paper's motion blur of the pictures ``look(states)``: half-weight copies at position
    -/+ ``delta`` overlaid, each image rescaled to [0, 1]."""
    out = 0.5 * look(states - delta) + look(states) + 0.5 * look(states + delta)
    return (out - out.min(axis=(1, 2), keepdims=True)) / np.ptp(out, axis=(1, 2), keepdims=True)


def images(states, *, seed=0, contrast=None, blur=None, glare=None, shift_cols=0, shadow=None, noise=0.01):
    """Camera images with hidden effects: PIL contrast, the paper's overlay blur, a glare disc,
    a camera turned by whole pixels (content moves right by ``shift_cols``, edge repeated), and
    ``shadow`` = (p_from, factor): beyond position p_from the scene is dimmed by ``factor`` (the
    car drives under a roof; no effect of the library does this)."""
    rng = np.random.default_rng(seed)

    def look(s):
        pictures = render(s)
        if contrast is not None:
            pictures = np.stack([_pil_contrast(p, contrast) for p in pictures])
        return pictures

    out = look(states) if blur is None else blurred(look, states, blur)
    if shift_cols:
        out = np.concatenate([np.repeat(out[:, :, :1], shift_cols, axis=2), out[:, :, :-shift_cols]], axis=2)
    if shadow is not None:
        start, factor = shadow
        out = np.where(np.asarray(states, dtype=float)[:, :1, None] > start, factor * out, out)
    if glare is not None:
        r0, c0, radius = glare
        rows, cols = np.mgrid[0:H, 0:WIDTH]
        out = np.where((rows - r0) ** 2 + (cols - c0) ** 2 <= radius**2, 1.0, out)
    out = np.clip(out + rng.normal(0, noise, out.shape), 0, 1)
    return out.reshape(len(states), -1)


# ---------------------------------------------------------------- dynamics
def mountain_car_step(states, controls):
    """The known plant (what the user models): one Mountain Car step with the left wall."""
    p, v = states[:, 0], states[:, 1]
    v = np.clip(v + 0.0015 * controls[:, 0] - 0.0025 * np.cos(3 * p), -0.07, 0.07)
    p = p + v
    stopped = p < -1.2
    return np.column_stack([np.where(stopped, -1.2, p), np.where(stopped, 0.0, v)])


def runs(n_runs, steps, *, seed=0, drag=0.0, delay=0, gain=1.0, noise=1e-5):
    """Mountain Car runs under random piecewise-constant thrust, with hidden drag, delay and gain.

    Returns (states, controls, trajectory, time) row-stacked by run.
    """
    rng = np.random.default_rng(seed)
    out = {"states": [], "controls": [], "trajectory": [], "time": []}
    for run in range(n_runs):
        holds = rng.integers(2, 6, size=steps)
        u = np.repeat(rng.uniform(-1, 1, size=steps), holds)[:steps]
        p, v = rng.uniform(-1.0, 0.2), rng.uniform(-0.03, 0.03)
        for k in range(steps):
            out["states"].append((p, v))
            out["controls"].append(u[k])
            out["trajectory"].append(run)
            out["time"].append(k * 0.1)
            applied = gain * u[max(k - delay, 0)]
            v = float(np.clip(v * (1 - drag) + 0.0015 * applied - 0.0025 * np.cos(3 * p), -0.07, 0.07))
            p = p + v
            if p < -1.2:
                p, v = -1.2, 0.0
            v += rng.normal(0, noise)
            p += rng.normal(0, noise)
    return (np.array(out["states"]), np.array(out["controls"])[:, None], np.array(out["trajectory"]), np.array(out["time"]))
