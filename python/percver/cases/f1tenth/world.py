"""The canonical F1/10 world: tracks, hallway-local coordinates, the controllers' LiDAR view.

World poses are ``(x, y, theta)`` in the frame of ``percver.sensors.lidar.square_track``:
outer walls [0, 20]^2, driven clockwise, the first hallway along x in [0, 1.5] heading north
into the first right turn at y = 20. The original verification models use hallway-local
coordinates of that first hallway, kept through the turn (REFERENCE.md):

    y1 = distance to the left (outer) wall  = x
    y2 = distance to the front wall         = 20 - y
    y4 = heading relative to the hallway     = theta - pi/2

``right_turn()`` is the single right turn of those models drawn in the same frame, so one
pose means the same thing on both tracks and the turn's ``Expr`` scan (``scan_exprs``) is
verified against the same numpy ray caster that simulates the loop.
"""

from __future__ import annotations

import numpy as np

from percver.errors import InputError
from percver.sensors.lidar import Hallway, Lidar, Track, square_track

WIDTH = 1.5
LENGTH = 20.0
# What the controllers see: 21 rays, ranges clipped at 5 m, normalised as (r - 2.5) / 5.
CONTROLLER_RANGE = 5.0
NORMALISATION_OFFSET = 2.5
NORMALISATION_SCALE = 0.2
# The 21 controller rays inside the 1081-ray scan (-115..115 degrees of -135..135 at 0.25 degrees).
RAYS21 = np.arange(80, 1001, 46)
# Raw readings at or below this are the scanner's "no echo" codes, not distances.
NO_ECHO = 0.02


def square() -> Track:
    """The simulated loop: 20 m square, 1.5 m hallways, four right turns."""
    return square_track(WIDTH, LENGTH)


def right_turn(width: float = WIDTH, length: float = LENGTH) -> Track:
    """The single right turn of the verification models, in the square loop's frame.

    The first hallway (x in [0, width], driving north) ends at the front wall y = ``length``;
    the second leaves eastwards between y = length - width and y = length. Walls run
    ``length`` metres, so within the LiDAR's range of the turn it equals the loop.
    """
    if not 0 < width < length:
        raise InputError(f"a right turn needs 0 < width < length, got width={width}, length={length}")
    w, L = float(width), float(length)
    segments = [
        ((0.0, 0.0), (0.0, L)),  # left (outer) wall of the first hallway
        ((0.0, L), (L, L)),  # front wall, then left wall of the second hallway
        ((w, 0.0), (w, L - w)),  # right (inner) wall of the first hallway
        ((w, L - w), (L, L - w)),  # right (inner) wall of the second hallway
    ]
    hallways = [Hallway((w / 2, 0.0), np.pi / 2, L, w), Hallway((w, L - w / 2), 0.0, L - w, w)]
    return Track(segments, hallways, name=f"right turn {w:g} m wide")


def controller_lidar() -> Lidar:
    return Lidar.f1tenth21()


def scanner() -> Lidar:
    """The real car's scanner: 1081 rays over -135..135 degrees, 10 m."""
    return Lidar.f1tenth1081()


def to_local(states, length: float = LENGTH) -> np.ndarray:
    """World poses (N x >=3: x, y, theta, ...) -> first-hallway coordinates (N x 3: y1, y2, y4)."""
    states = np.atleast_2d(np.asarray(states, dtype=float))
    y4 = (states[:, 2] - np.pi / 2 + np.pi) % (2 * np.pi) - np.pi
    return np.column_stack([states[:, 0], length - states[:, 1], y4])


def from_local(local, length: float = LENGTH) -> np.ndarray:
    """First-hallway coordinates (N x 3: y1, y2, y4) -> world poses (N x 3: x, y, theta)."""
    local = np.atleast_2d(np.asarray(local, dtype=float))
    return np.column_stack([local[:, 0], length - local[:, 1], local[:, 2] + np.pi / 2])


def scan_exprs(y1="y1", y2="y2", y4="y4", *, lidar: Lidar | None = None, track: Track | None = None) -> list:
    """The canonical scan g_c(y1, y2, y4) of the right turn as expressions, one per ray.

    The arguments are variables or names of the hallway-local state; ``lidar`` defaults to the
    controllers' 21 rays (5 m). This is the piecewise model of the paper's Appendix B.2 (which
    wall a ray hits depends on the pose), equal on floats to ``lidar.scan(right_turn(), ...)``.
    """
    from percver import expr as px

    y1, y2, y4 = (px.Expr.var(v) if isinstance(v, str) else v for v in (y1, y2, y4))
    lidar = lidar or controller_lidar()
    return lidar.exprs(track or right_turn(), y1, LENGTH - y2, y4 + np.pi / 2)


def normalise(ranges) -> np.ndarray:
    """Ranges in metres -> controller inputs: clipped at 5 m, (r - 2.5) / 5 (max range -> 0.5)."""
    ranges = np.minimum(np.asarray(ranges, dtype=float), CONTROLLER_RANGE)
    return (ranges - NORMALISATION_OFFSET) * NORMALISATION_SCALE


def denormalise(values) -> np.ndarray:
    return np.asarray(values, dtype=float) / NORMALISATION_SCALE + NORMALISATION_OFFSET


def controller_view(raw) -> np.ndarray:
    """Raw 1081-ray scans (metres, ``NO_ECHO`` codes for no return) -> the 21 controller ranges:
    no echo and anything beyond 5 m read 5 m, as on the car."""
    raw = np.atleast_2d(np.asarray(raw, dtype=float))
    if raw.shape[1] != 1081:
        raise InputError(f"raw scans need 1081 rays per row, got {raw.shape[1]}; pass the full scanner output")
    rays = raw[:, RAYS21]
    return np.where(rays <= NO_ECHO, CONTROLLER_RANGE, np.minimum(rays, CONTROLLER_RANGE))


def pose_features(local) -> np.ndarray:
    """The noise classifier's pose inputs (REFERENCE.md): 0.1 y1, 0.1 (10 - y2), y4 / (1.5 pi) + 1/3."""
    local = np.atleast_2d(np.asarray(local, dtype=float))
    return np.column_stack([0.1 * local[:, 0], 0.1 * (10.0 - local[:, 1]), local[:, 2] / (1.5 * np.pi) + 1.0 / 3.0])


def wall_distance(track: Track, states) -> np.ndarray:
    """Distance from each pose's (x, y) to the nearest wall segment."""
    states = np.atleast_2d(np.asarray(states, dtype=float))
    point = states[:, None, :2]
    p0 = track.segments[None, :, 0]
    edge = track.segments[None, :, 1] - track.segments[None, :, 0]
    t = np.clip(((point - p0) * edge).sum(-1) / (edge**2).sum(-1), 0.0, 1.0)
    return np.linalg.norm(p0 + t[..., None] * edge - point, axis=-1).min(axis=1)
