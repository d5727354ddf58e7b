"""Tracks of straight walls and a planar LiDAR cast against them: the canonical scan g_c.

This numpy ray caster is the float reference of the canonical LiDAR: the piecewise ``Expr``
form used for verification must agree with it. States are ``(x, y, theta)`` in the track's
world frame (metres, radians, theta measured from the x axis, counter-clockwise); ray
angles are relative to the heading, negative to the right. A ray that hits nothing within
the maximum range reads the maximum range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from percver.errors import InputError
from percver.validate.models import BatchCache, SensorModel

# Rows of poses cast per batch, so that a (rows x rays x walls) block stays near 4 million numbers.
_BLOCK = 4_000_000


@dataclass(frozen=True)
class Hallway:
    """A straight stretch the car drives along: entry at ``start`` (centre of the entry edge),
    driving direction ``heading`` (radians), ``length`` along it and ``width`` across it."""

    start: tuple
    heading: float
    length: float
    width: float

    def local(self, x, y):
        """(along, across) coordinates; across is positive to the left of the driving direction."""
        dx, dy = np.asarray(x) - self.start[0], np.asarray(y) - self.start[1]
        c, s = np.cos(self.heading), np.sin(self.heading)
        return dx * c + dy * s, -dx * s + dy * c

    def world(self, along, across):
        c, s = np.cos(self.heading), np.sin(self.heading)
        return self.start[0] + along * c - across * s, self.start[1] + along * s + across * c


class Track:
    """Walls as line segments (K x 2 x 2, metres) and the hallways a car drives through.

    Wall coordinates run along the segments in order (segment k covers
    ``offsets[k] .. offsets[k] + lengths[k]``), so a place on any wall is one number; the
    specular-reflection effect describes its panel that way. Progress runs along the hallways.
    """

    def __init__(self, segments, hallways=(), name: str = "track"):
        segments = np.asarray(segments, dtype=float)
        if segments.ndim != 3 or segments.shape[1:] != (2, 2) or len(segments) == 0:
            raise InputError(f"track segments must have shape (K, 2, 2), got {segments.shape}")
        self.segments = segments
        self.lengths = np.hypot(*(segments[:, 1] - segments[:, 0]).T)
        if np.any(self.lengths <= 0):
            raise InputError(f"track segments {np.flatnonzero(self.lengths <= 0).tolist()} have zero length")
        self.offsets = np.concatenate([[0.0], np.cumsum(self.lengths)[:-1]])
        self.hallways = tuple(hallways)
        self.name = name

    @property
    def wall_length(self) -> float:
        return float(self.lengths.sum())

    def __repr__(self) -> str:
        return f"Track({self.name!r}, {len(self.segments)} walls, {len(self.hallways)} hallways)"

    def wall_point(self, s):
        """World (x, y) of wall coordinates ``s``."""
        s = np.asarray(s, dtype=float)
        k = np.clip(np.searchsorted(self.offsets, s, side="right") - 1, 0, len(self.segments) - 1)
        fraction = (s - self.offsets[k]) / self.lengths[k]
        p0, p1 = self.segments[k, 0], self.segments[k, 1]
        point = p0 + fraction[..., None] * (p1 - p0)
        return point[..., 0], point[..., 1]

    def wall_position(self, x, y):
        """Wall coordinate of the wall point nearest to (``x``, ``y``), e.g. to place a panel."""
        point = np.stack(np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float)), axis=-1)
        p0, edge = self.segments[:, 0], self.segments[:, 1] - self.segments[:, 0]
        t = np.clip(((point[..., None, :] - p0) * edge).sum(-1) / self.lengths**2, 0.0, 1.0)
        distance = np.linalg.norm(p0 + t[..., None] * edge - point[..., None, :], axis=-1)
        k = np.argmin(distance, axis=-1)
        return self.offsets[k] + np.take_along_axis(t, k[..., None], -1)[..., 0] * self.lengths[k]

    def sample_poses(self, n: int, seed=None, *, margin: float = 0.25, heading_spread_deg: float = 30.0):
        """``n`` poses (x, y, theta) uniformly inside the hallways, at least ``margin`` from the
        side and front walls, heading within ``heading_spread_deg`` of the driving direction."""
        if not self.hallways:
            raise InputError(f"track {self.name!r} has no hallways to sample poses in")
        rng = np.random.default_rng(seed)
        lengths = np.array([h.length for h in self.hallways])
        which = rng.choice(len(self.hallways), size=n, p=lengths / lengths.sum())
        poses = np.empty((n, 3))
        for k, hallway in enumerate(self.hallways):
            rows = which == k
            count = int(rows.sum())
            half = hallway.width / 2 - margin
            if half <= 0:
                raise InputError(f"margin {margin} leaves no room in a hallway {hallway.width} m wide")
            along = rng.uniform(0, hallway.length - margin, count)
            across = rng.uniform(-half, half, count)
            poses[rows, 0], poses[rows, 1] = hallway.world(along, across)
            spread = np.radians(heading_spread_deg)
            poses[rows, 2] = _wrap(hallway.heading + rng.uniform(-spread, spread, count))
        return poses

    def locate(self, states) -> dict:
        """Where poses are: ``hallway`` index (-1 outside all), ``progress`` along the loop (m),
        ``across`` (m, left positive) and ``heading`` relative to the hallway (radians)."""
        states = np.atleast_2d(np.asarray(states, dtype=float))
        out = {key: np.full(len(states), np.nan) for key in ("progress", "across", "heading")}
        out["hallway"] = np.full(len(states), -1)
        done = np.zeros(len(states), dtype=bool)
        offset = 0.0
        for k, hallway in enumerate(self.hallways):
            along, across = hallway.local(states[:, 0], states[:, 1])
            inside = ~done & (along >= 0) & (along <= hallway.length) & (np.abs(across) <= hallway.width / 2)
            out["hallway"][inside] = k
            out["progress"][inside] = offset + along[inside]
            out["across"][inside] = across[inside]
            out["heading"][inside] = _wrap(states[inside, 2] - hallway.heading)
            done |= inside
            offset += hallway.length
        return out


# Floor on the approach speed of a ray toward a wall's line in ``Lidar.exprs``: keeps every
# division finite on sets; exact on floats farther than max_range * _GRAZING from the line.
_GRAZING = 1e-12


def _affine(constant: float, *terms):
    """``constant + sum(coefficient * expression)`` as an expression, leaving out zero terms
    (axis-aligned walls have zero components) so that the DAG stays small."""
    from percver import expr as px

    total = None
    for coefficient, value in terms:
        if coefficient == 0.0:
            continue
        term = value if coefficient == 1.0 else -value if coefficient == -1.0 else coefficient * value
        total = term if total is None else total + term
    if total is None:
        return px.as_expr(constant)
    return total + constant if constant != 0.0 else total


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def square_track(width: float = 1.5, length: float = 20.0) -> Track:
    """The F1/10 square loop: outer walls ``length`` m square, hallways ``width`` m wide, driven
    clockwise so that every turn is a right turn. The outer square spans [0, length]^2.

    Each hallway ends with the corner in which the car turns (a pinwheel split of the loop),
    so hallway-local coordinates match the single-turn verification models.
    """
    if not 0 < 2 * width < length:
        raise InputError(f"a square track needs 0 < 2 * width < length, got width={width}, length={length}")
    L, w = float(length), float(width)
    outer = [(0, 0), (0, L), (L, L), (L, 0)]
    inner = [(w, w), (w, L - w), (L - w, L - w), (L - w, w)]
    segments = [(outer[i], outer[(i + 1) % 4]) for i in range(4)] + [(inner[i], inner[(i + 1) % 4]) for i in range(4)]
    straight = L - w
    hallways = [
        Hallway((w / 2, w), np.pi / 2, straight, w),  # west side, driving north
        Hallway((w, L - w / 2), 0.0, straight, w),  # north side, driving east
        Hallway((L - w / 2, L - w), -np.pi / 2, straight, w),  # east side, driving south
        Hallway((L - w, w / 2), np.pi, straight, w),  # south side, driving west
    ]
    return Track(segments, hallways, name=f"square {L:g} m x {w:g} m")


@dataclass(frozen=True)
class Hits:
    """Where each ray first meets a wall (N poses x R rays).

    ``range`` is the unclipped distance (inf when nothing is hit), ``segment`` the wall index
    (-1 for none), ``along`` the distance of the hit from the segment's start, and
    ``cos_incidence`` the cosine of the angle between the ray and the wall's normal
    (1 = head-on, 0 = grazing).
    """

    range: np.ndarray
    segment: np.ndarray
    along: np.ndarray
    cos_incidence: np.ndarray

    def wall_coordinate(self, track: Track) -> np.ndarray:
        """Hit positions as track wall coordinates (NaN where nothing is hit)."""
        hit = self.segment >= 0
        return np.where(hit, track.offsets[np.maximum(self.segment, 0)] + self.along, np.nan)


class Lidar:
    """A planar scanning range sensor: ray angles relative to the heading and a range limit."""

    def __init__(self, angles_deg, max_range: float):
        self.angles_deg = np.asarray(angles_deg, dtype=float).ravel()
        if self.angles_deg.size == 0:
            raise InputError("a LiDAR needs at least one ray angle")
        if not max_range > 0:
            raise InputError(f"max_range must be positive, got {max_range}")
        self.max_range = float(max_range)
        self.angles = np.radians(self.angles_deg)

    @classmethod
    def f1tenth21(cls) -> "Lidar":
        """The 21 rays the F1/10 controllers read: -115..115 degrees in 11.5 degree steps, 5 m."""
        return cls(np.linspace(-115.0, 115.0, 21), 5.0)

    @classmethod
    def f1tenth1081(cls) -> "Lidar":
        """The full F1/10 sensor: 1081 rays over -135..135 degrees (0.25 degree steps), 10 m."""
        return cls(np.linspace(-135.0, 135.0, 1081), 10.0)

    def with_range(self, max_range: float) -> "Lidar":
        """The same rays with another range limit."""
        return Lidar(self.angles_deg, max_range)

    @property
    def names(self) -> tuple:
        return tuple(f"ray{i}" for i in range(len(self.angles)))

    def __repr__(self) -> str:
        return f"Lidar({len(self.angles)} rays, {self.angles_deg[0]:g}..{self.angles_deg[-1]:g} deg, max_range={self.max_range:g} m)"

    def cast(self, track: Track, x, y, theta) -> Hits:
        """Cast every ray from every pose against every wall (vectorised, in blocks of poses)."""
        x, y, theta = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x, y, theta))
        n, n_rays = len(x), len(self.angles)
        p0 = track.segments[:, 0]
        edge = track.segments[:, 1] - p0
        out = Hits(
            range=np.empty((n, n_rays)),
            segment=np.empty((n, n_rays), dtype=np.int64),
            along=np.empty((n, n_rays)),
            cos_incidence=np.empty((n, n_rays)),
        )
        block = max(1, _BLOCK // (n_rays * len(p0)))
        for lo in range(0, n, block):
            rows = slice(lo, min(n, lo + block))
            angle = theta[rows, None] + self.angles[None, :]
            dx, dy = np.cos(angle)[..., None], np.sin(angle)[..., None]
            # Ray p + t d meets segment p0 + u e where t, u solve a 2x2 system (Cramer's rule).
            wx = (p0[:, 0] - x[rows, None])[:, None, :]
            wy = (p0[:, 1] - y[rows, None])[:, None, :]
            det = dx * edge[:, 1] - dy * edge[:, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (wx * edge[:, 1] - wy * edge[:, 0]) / det
                u = (wx * dy - wy * dx) / det
            valid = (np.abs(det) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
            t = np.where(valid, t, np.inf)
            first = np.argmin(t, axis=-1)
            distance = np.take_along_axis(t, first[..., None], axis=-1)[..., 0]
            hit = np.isfinite(distance)
            out.range[rows] = distance
            out.segment[rows] = np.where(hit, first, -1)
            out.along[rows] = np.where(hit, np.take_along_axis(u, first[..., None], -1)[..., 0] * track.lengths[first], np.nan)
            cos = np.abs(np.take_along_axis(det, first[..., None], -1)[..., 0]) / track.lengths[first]
            out.cos_incidence[rows] = np.where(hit, cos, np.nan)
        return out

    def ranges(self, track: Track, x, y, theta) -> np.ndarray:
        """``cast(...).range`` (N x R, inf where nothing is hit) computing only what the range
        needs, for hot loops such as particle filters: the same t and the same tests as ``cast``
        (``u`` in [0, 1] checked as ``u * det**2`` against ``det**2``, without dividing)."""
        x, y, theta = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x, y, theta))
        n, n_rays = len(x), len(self.angles)
        p0 = track.segments[:, 0]
        ex, ey = (track.segments[:, 1] - p0).T
        out = np.empty((n, n_rays))
        block = max(1, _BLOCK // (n_rays * len(p0)))
        for lo in range(0, n, block):
            rows = slice(lo, min(n, lo + block))
            angle = theta[rows, None] + self.angles[None, :]
            dx, dy = np.cos(angle)[..., None], np.sin(angle)[..., None]
            wx = (p0[:, 0] - x[rows, None])[:, None, :]
            wy = (p0[:, 1] - y[rows, None])[:, None, :]
            det = dx * ey - dy * ex
            numerator = wx * ey - wy * ex
            with np.errstate(divide="ignore", invalid="ignore"):
                t = numerator / det
            u_scaled = (wx * dy - wy * dx) * det
            valid = (np.abs(det) > 1e-12) & (t > 0) & (u_scaled >= 0) & (u_scaled <= det * det)
            out[rows] = np.where(valid, t, np.inf).min(axis=-1)
        return out

    def scan(self, track: Track, states) -> np.ndarray:
        """Canonical ranges (N x R), clipped at ``max_range``."""
        states = np.atleast_2d(np.asarray(states, dtype=float))
        return np.minimum(self.cast(track, states[:, 0], states[:, 1], states[:, 2]).range, self.max_range)

    def exprs(self, track: Track, x, y, theta) -> list:
        """The canonical ranges as expressions of the pose, one per ray, for verification.

        ``x``, ``y``, ``theta`` are expressions (``pv.variables``) or variable names; any
        expressions of other variables work too, e.g. hallway-local coordinates. The form is the
        hybrid model of the paper's Appendix B.2 written with ``pv.where``: for every wall, the
        distance along the ray to the wall's line counts only where the hit lies on the wall
        (which wall a ray hits depends on the pose), and the ray reads the nearest such hit,
        clipped at ``max_range``. On floats it equals ``scan`` (up to rounding) except within
        ``max_range * _GRAZING`` metres of a wall's line, where ``scan`` is ill-conditioned too.

        No branch divides by a quantity that can vanish (a ray parallel to a wall reads
        ``max_range`` through a floor on the denominator), so interval and Taylor-model
        evaluation stay finite whichever way a condition is decided.
        """
        from percver import expr as px

        x, y, theta = (px.Expr.var(v) if isinstance(v, str) else px.as_expr(v) for v in (x, y, theta))
        limit = self.max_range
        walls = []
        for (x0, y0), (x1, y1) in track.segments:
            length = float(np.hypot(x1 - x0, y1 - y0))
            ex, ey = (x1 - x0) / length, (y1 - y0) / length
            nx, ny = -ey, ex
            # Signed distance from the pose to the wall's line along its left normal, and the
            # pose's position along the wall.
            gap = _affine(nx * x0 + ny * y0, (-nx, x), (-ny, y))
            along = _affine(-(ex * x0 + ey * y0), (ex, x), (ey, y))
            walls.append((gap, px.abs_(gap), along, (nx, ny), (ex, ey), length))
        out = []
        for alpha in self.angles:
            heading = theta + float(alpha) if alpha != 0 else theta
            c, s = px.cos(heading), px.sin(heading)
            nearest = None
            for gap, distance, along, (nx, ny), (ex, ey), length in walls:
                toward = _affine(0.0, (nx, c), (ny, s))  # speed at which the ray approaches the line
                toward = px.where(gap >= 0, toward, -toward)
                # t <= limit by construction: a ray that cannot reach the line within range reads the limit.
                t = distance / px.maximum(px.maximum(toward, distance / limit), _GRAZING)
                # Which wall is hit, decided without dividing (hit position times toward, as in
                # ``ranges``): on sets near a wall's line, distance / toward is loose, and the
                # hull of a wrongly undecided miss spoils the ray (verification of the turn).
                scaled = along * toward + distance * _affine(0.0, (ex, c), (ey, s))
                hit = px.where(scaled >= 0.0, px.where(scaled <= length * toward, t, limit), limit)
                # Strict: a ray along a line it starts on (toward = distance = 0) hits nothing.
                reading = px.where(toward * limit > distance, hit, limit)
                nearest = reading if nearest is None else px.minimum(nearest, reading)
            out.append(nearest)
        return out


class LidarModel(SensorModel):
    """The canonical LiDAR on a track with a stack of effects (``percver.validate.effects``).

    Effects that move the sensor (mounting yaw and position) act before the rays are cast,
    in order; the others act on the ranges afterwards, in order; then ranges are clipped at
    the range limit (which a ``max_range`` effect may change).
    """

    kind = "lidar"

    def __init__(self, track: Track, lidar: Lidar, effects=()):
        super().__init__(("x", "y", "theta"), lidar.names, effects)
        self.track = track
        self.lidar = lidar
        self._cache = BatchCache()

    def describe(self) -> str:
        effects = ", ".join(repr(e) for e in self.effects) or "no effects"
        return f"canonical LiDAR, {self.lidar!r} on {self.track!r} ({effects})"

    def range_limit(self) -> float:
        limit = self.lidar.max_range
        for effect in self.deterministic_effects:
            limit = effect.limit(limit)
        return limit

    def hits(self, states) -> Hits:
        """Ray hits from the sensor pose implied by ``states`` and the mounting effects
        (cached per states array and mounting: range effects do not need a new cast)."""
        mounting = tuple(e for e in self.effects if e.moves_sensor)

        def cast():
            x, y, theta = states[:, 0], states[:, 1], states[:, 2]
            for effect in mounting:
                x, y, theta = effect.mount(x, y, theta)
            return self.lidar.cast(self.track, x, y, theta)

        return self._cache.get(states, mounting, cast)

    def predict_inputs(self, inputs):
        states = inputs["states"]
        hits = self.hits(states)
        ranges = hits.range
        for effect in self.deterministic_effects:
            ranges = effect.ranges(ranges, hits, self)
        return np.minimum(ranges, self.range_limit())

    def clip(self, values):
        return np.clip(values, 0.0, self.range_limit())

    def features(self, states):
        where = self.track.locate(states)
        return {
            "x": states[:, 0],
            "y": states[:, 1],
            "theta": states[:, 2],
            "progress": where["progress"],
            "heading_deg": np.degrees(where["heading"]),
        }

    @property
    def region_variables(self):
        return ("progress", "heading_deg") if self.track.hallways else ("x", "y")


def canonical(track: Track | None = None, lidar: Lidar | None = None) -> LidarModel:
    """The canonical LiDAR model g_c: ``lidar`` (F1/10's 21 rays) on ``track`` (the square loop)."""
    return LidarModel(track if track is not None else square_track(), lidar if lidar is not None else Lidar.f1tenth21())
