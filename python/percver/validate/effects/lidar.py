"""LiDAR effects: what a real scanner does that the canonical ray caster does not."""

from __future__ import annotations

import numpy as np

from percver.validate.effects.base import Effect

# A ray "without echo" reads the range limit exactly; one that should echo is predicted at
# least this fraction of the limit closer.
_ECHO_GAP = 0.02


def _no_echo(predicted, measured, limit):
    """Rays predicted to echo that read the range limit."""
    return (predicted < limit * (1 - _ECHO_GAP)) & (measured >= limit * (1 - 1e-9))


class LidarEffect(Effect):
    """Base of LiDAR effects: hooks before the cast (``mount``), on ranges, on the limit.

    The ``*_expr`` hooks are the expression forms (``p``: parameters as numbers or
    ``pv.uncertain`` ranges): the mounting on the pose, the range map as an affine map
    ``a r + b`` of the echo distance, the limit. ``knockout`` effects (random or
    hit-dependent lost echoes) enter a verified scan as an adversarial knock-out: any ray may
    read the range limit at any step."""

    kinds = ("lidar",)
    knockout = False

    def mount(self, x, y, theta):
        return x, y, theta

    def ranges(self, ranges, hits, model):
        return ranges

    def limit(self, limit):
        return limit

    def mount_expr(self, x, y, theta, p):
        return x, y, theta

    def affine_expr(self, a, b, p):
        return a, b

    def limit_expr(self, limit, p):
        return limit


class RangeBias(LidarEffect):
    """Range offset: every echo reads ``bias`` metres long (timing offset, miscalibrated zero).

    Positive bias reads walls farther than they are."""

    name = "range_bias"
    stage = 3
    defaults = {"bias": 0.0}
    bounds = {"bias": (-0.5, 0.5)}
    units = {"bias": "m"}

    def ranges(self, ranges, hits, model):
        return ranges + self.params["bias"]

    def affine_expr(self, a, b, p):
        return a, b + p["bias"]


class RangeScale(LidarEffect):
    """Range scale error: echoes read ``scale`` times the true distance (clock-rate error)."""

    name = "range_scale"
    stage = 3
    defaults = {"scale": 1.0}
    bounds = {"scale": (0.8, 1.25)}

    def ranges(self, ranges, hits, model):
        return ranges * self.params["scale"]

    def affine_expr(self, a, b, p):
        return a * p["scale"], b * p["scale"]


class AngleOffset(LidarEffect):
    """Mounting yaw: the scanner is turned ``yaw_deg`` degrees (counter-clockwise) on the car."""

    name = "angle_offset"
    defaults = {"yaw_deg": 0.0}
    bounds = {"yaw_deg": (-20.0, 20.0)}
    units = {"yaw_deg": "deg"}
    moves_sensor = True

    def mount(self, x, y, theta):
        return x, y, theta + np.radians(self.params["yaw_deg"])

    def mount_expr(self, x, y, theta, p):
        return x, y, theta + p["yaw_deg"] * (np.pi / 180.0)


class PositionOffset(LidarEffect):
    """Mounting position: the scanner sits ``forward`` and ``left`` metres from the car's reference point."""

    name = "position_offset"
    defaults = {"forward": 0.0, "left": 0.0}
    bounds = {"forward": (-0.3, 0.3), "left": (-0.3, 0.3)}
    units = {"forward": "m", "left": "m"}
    moves_sensor = True

    def mount(self, x, y, theta):
        c, s = np.cos(theta), np.sin(theta)
        f, l = self.params["forward"], self.params["left"]
        return x + f * c - l * s, y + f * s + l * c, theta

    def mount_expr(self, x, y, theta, p):
        from percver.expr import cos, sin

        c, s = cos(theta), sin(theta)
        f, l = p["forward"], p["left"]
        return x + f * c - l * s, y + f * s + l * c, theta


class MaxRange(LidarEffect):
    """A different range limit: echoes beyond ``limit`` metres are lost (weak returns, dark walls),
    so rays read at most ``limit``."""

    name = "max_range"
    stage = 2
    defaults = {"limit": None}
    bounds = {"limit": (0.0, np.inf)}
    units = {"limit": "m"}
    smooth = False

    def limit(self, limit):
        return limit if self.params["limit"] is None else self.params["limit"]

    def limit_expr(self, limit, p):
        return limit if p["limit"] is None else p["limit"]

    def search_bounds(self, model, evaluation):
        nominal = model.lidar.max_range
        return {"limit": (0.2 * nominal, 2.0 * nominal)}

    def search_width(self, model, evaluation):
        return {"limit": 0.1 * model.lidar.max_range}

    def starts(self, model, evaluation, predicted):
        return [{"limit": float(np.max(evaluation.measured))}]


class SpecularReflection(LidarEffect):
    """A reflective (metallic) wall panel: rays hitting it beyond ``threshold_deg`` degrees of
    incidence are mirrored away and read the range limit.

    The panel spans wall coordinates ``start`` .. ``end`` (metres along the track's walls, see
    ``Track.wall_point``). Each instance is one panel; several may be stacked."""

    name = "specular_reflection"
    stage = 1
    defaults = {"start": 0.0, "end": 0.0, "threshold_deg": 90.0}
    bounds = {"start": (0.0, np.inf), "end": (0.0, np.inf), "threshold_deg": (0.0, 90.0)}
    units = {"start": "m", "end": "m", "threshold_deg": "deg"}
    smooth = False
    repeatable = True
    # Which rays it mirrors depends on the hit point and the incidence; verified as a knock-out
    # of any ray (sound, looser than the panel alone).
    knockout = True

    def ranges(self, ranges, hits, model):
        where = hits.wall_coordinate(model.track)
        incidence = np.degrees(np.arccos(np.clip(hits.cos_incidence, 0.0, 1.0)))
        with np.errstate(invalid="ignore"):
            mirrored = (where >= self.params["start"]) & (where <= self.params["end"])
            mirrored &= incidence > self.params["threshold_deg"]
        return np.where(mirrored, np.inf, ranges)

    def search_bounds(self, model, evaluation):
        total = model.track.wall_length
        return {"start": (0.0, total), "end": (0.0, total), "threshold_deg": (0.0, 90.0)}

    def search_width(self, model, evaluation):
        return {"start": 4.0, "end": 4.0, "threshold_deg": 30.0}

    def applicable(self, model, evaluation):
        """Only rays that should echo but read the limit can be explained by a mirror."""
        predicted = model.predict_inputs(evaluation.inputs)
        return hasattr(model, "track") and _no_echo(predicted, evaluation.measured, model.range_limit()).sum() >= 3

    def starts(self, model, evaluation, predicted):
        """Put the panel where rays that should echo read the limit most densely."""
        lost = _no_echo(predicted, evaluation.measured, model.range_limit())
        hits = model.hits(evaluation.inputs["states"])
        where = hits.wall_coordinate(model.track)
        lost &= np.isfinite(where)
        bin_width = 0.25
        edges = np.arange(0.0, model.track.wall_length + bin_width, bin_width)
        lost_count = np.histogram(where[lost], edges)[0]
        hit_count = np.histogram(where[np.isfinite(where)], edges)[0]
        # Smoothed over a metre, so that stretches hit only head-on do not split the panel.
        share = np.convolve(lost_count / np.maximum(hit_count, 1), np.ones(5) / 5, mode="same")
        peak = int(np.argmax(lost_count))
        lo = hi = peak
        while lo > 0 and share[lo - 1] >= 0.2 * share[peak]:
            lo -= 1
        while hi < len(share) - 1 and share[hi + 1] >= 0.2 * share[peak]:
            hi += 1
        panel = (where >= edges[lo]) & (where <= edges[hi + 1])
        incidence = np.degrees(np.arccos(np.clip(hits.cos_incidence[lost & panel], 0, 1)))
        threshold = float(np.percentile(incidence, 5)) - 1.0 if incidence.size else 45.0
        region = {"start": float(edges[lo]), "end": float(edges[hi + 1])}
        return [{**region, "threshold_deg": max(threshold, 0.0)}, {**region, "threshold_deg": 0.0}]


class Dropout(LidarEffect):
    """Random lost echoes: each ray independently reads the range limit with probability ``rate``
    (dust, absorbing spots, interference)."""

    name = "dropout"
    stage = 9
    defaults = {"rate": 0.0}
    bounds = {"rate": (0.0, 1.0)}
    stochastic = True
    knockout = True

    def fit_stochastic(self, model, evaluation, predicted):
        limit = model.range_limit()
        echoing = predicted < limit * (1 - _ECHO_GAP)
        lost = _no_echo(predicted, evaluation.measured, limit)
        return self.replace(rate=float(lost.sum() / max(echoing.sum(), 1)))

    def accounts(self, predicted, measured, model):
        if self.params["rate"] <= 0:
            return np.zeros(measured.shape, dtype=bool)
        return _no_echo(predicted, measured, model.range_limit())

    def sample(self, values, rng, model):
        return np.where(rng.random(values.shape) < self.params["rate"], model.range_limit(), values)


EFFECTS = (RangeBias, RangeScale, AngleOffset, PositionOffset, MaxRange, SpecularReflection, Dropout)
