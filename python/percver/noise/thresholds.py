"""Labels of knocked-out entries by a threshold t_Delta, and per-output probability thresholds.

The paper (section 4.2) labels an entry of a real measurement as knocked out (adversarial) when
it differs from the canonical prediction by more than t_Delta, and picks t_Delta* to minimise the
error between the *noised* canonical measurements (labelled entries replaced by the knocked
value, e.g. a LiDAR's range limit) and the real ones. A classifier then predicts the labels, and
per-output thresholds turn its probabilities into knock-outs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from percver.errors import InputError

METRICS = ("mae", "mse")


def label(real, canonical, threshold) -> np.ndarray:
    """n = 1 where |real - canonical| > t_Delta (booleans, the shape of the measurements)."""
    return np.abs(np.asarray(real) - np.asarray(canonical)) > threshold


def replacements(real, labels, knocked) -> np.ndarray:
    """The value a knocked-out entry reads, per output: ``knocked`` itself (a number or one per
    output), or with ``knocked="mean"`` the mean real value of the labelled entries of each
    output (the least-squares choice; NaN for an output without labels)."""
    real = np.asarray(real, dtype=float)
    if isinstance(knocked, str):
        if knocked != "mean":
            raise InputError(f"knocked must be a number, one per output, or 'mean'; got {knocked!r}")
        count = labels.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, (real * labels).sum(axis=0) / count, np.nan)
    return np.broadcast_to(np.asarray(knocked, dtype=float), real.shape[1:]).copy()


def noised(real, canonical, threshold, knocked) -> np.ndarray:
    """The canonical measurements with the entries labelled at ``threshold`` replaced (see ``replacements``)."""
    labels = label(real, canonical, threshold)
    return np.where(labels, replacements(real, labels, knocked), canonical)


@dataclass(frozen=True)
class ThresholdCurve:
    """Error between noised canonical and real measurements for each candidate t_Delta (the last
    candidate lies beyond every difference: the canonical model alone), the share of entries
    labelled, and the minimiser ``best`` (t_Delta*)."""

    thresholds: np.ndarray
    errors: np.ndarray
    knocked_share: np.ndarray

    @property
    def best(self) -> float:
        return float(self.thresholds[int(np.argmin(self.errors))])

    def summary(self) -> dict:
        k = int(np.argmin(self.errors))
        return {
            "t_delta": self.best,
            "error_at_best": float(self.errors[k]),
            "knocked_share_at_best": float(self.knocked_share[k]),
            "error_without_noise_model": float(self.errors[-1]),
        }


def _pair(real, canonical) -> tuple:
    real, canonical = np.asarray(real, dtype=float), np.asarray(canonical, dtype=float)
    if real.shape != canonical.shape:
        raise InputError(f"real measurements {real.shape} and canonical ones {canonical.shape} must have the same shape")
    return real, canonical


def threshold_errors(real, canonical, thresholds, knocked, metric: str = "mae") -> tuple:
    """(error, share of entries labelled) of the noised canonical measurements per threshold;
    the error is the mean absolute ("mae", the paper's) or squared ("mse") difference."""
    if metric not in METRICS:
        raise InputError(f"unknown metric '{metric}'; use one of {METRICS}")
    real, canonical = _pair(real, canonical)
    difference = np.abs(real - canonical)
    errors = np.empty(len(thresholds))
    share = np.empty(len(thresholds))
    for i, t in enumerate(thresholds):
        labels = difference > t
        value = np.where(labels, np.nan_to_num(replacements(real, labels, knocked)), canonical) - real
        errors[i] = np.abs(value).mean() if metric == "mae" else np.mean(value**2)
        share[i] = labels.mean()
    return errors, share


def threshold_curve(real, canonical, thresholds=None, *, knocked, metric: str = "mae") -> ThresholdCurve:
    """The error per candidate t_Delta (default: 80 geometric steps from the median difference to
    the largest, then one beyond every difference)."""
    real, canonical = _pair(real, canonical)
    if thresholds is None:
        difference = np.abs(real - canonical)
        positive = difference[difference > 0]
        if positive.size == 0:
            thresholds = np.array([np.inf])
        else:
            low = max(float(np.median(positive)), float(positive.max()) * 1e-6)
            thresholds = np.concatenate([np.geomspace(low, positive.max(), 80), [np.inf]])
    thresholds = np.asarray(thresholds, dtype=float)
    errors, share = threshold_errors(real, canonical, thresholds, knocked, metric)
    return ThresholdCurve(thresholds, errors, share)


def fit_thresholds(probabilities, labels, grid=None, weights=None) -> np.ndarray:
    """Per output, the threshold of ``grid`` (default 100 points in [0, 1], as the paper's authors)
    with the highest accuracy on (probabilities, labels). ``weights`` (one per entry) make it a
    weighted accuracy, e.g. the error a knock-out removes or adds, so that thresholds minimise
    error rather than count mistakes; a threshold of 1 knocks nothing out."""
    grid = np.linspace(0.0, 1.0, 100) if grid is None else np.asarray(grid, dtype=float)
    probabilities, labels = np.asarray(probabilities), np.asarray(labels, dtype=bool)
    weights = np.ones(labels.shape) if weights is None else np.asarray(weights, dtype=float)
    score = np.stack([(((probabilities > t) == labels) * weights).mean(axis=0) for t in grid])
    return grid[np.argmax(score, axis=0)]
