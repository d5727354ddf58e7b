"""Adaptive binning of state space: where a per-row quantity (error, event count) is concentrated."""

from __future__ import annotations

import numpy as np


def standout(inside: np.ndarray, values: np.ndarray) -> tuple:
    """(lift, t statistic) of the mean of ``values[inside]`` against the rest."""
    a, b = values[inside], values[~inside]
    overall = values.mean() if values.mean() > 0 else 1.0
    if len(a) < 2 or len(b) < 2:
        return a.mean() / overall if len(a) else 0.0, 0.0
    spread = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    t = (a.mean() - b.mean()) / spread if spread > 0 else (np.inf if a.mean() > b.mean() else 0.0)
    return a.mean() / overall, t


def split_regions(table: np.ndarray, errors: np.ndarray, max_regions: int, min_count: int) -> list:
    """Adaptive binning: a regression tree on per-row error, splitting where error changes most."""
    leaves = [np.arange(len(errors))]
    while len(leaves) < max_regions:
        best = None
        for index, rows in enumerate(leaves):
            if len(rows) < 2 * min_count:
                continue
            e = errors[rows]
            for column in range(table.shape[1]):
                values = table[rows, column]
                for cut in np.unique(np.quantile(values, np.linspace(0.1, 0.9, 9))):
                    left = values <= cut
                    n_left = left.sum()
                    if n_left < min_count or len(rows) - n_left < min_count:
                        continue
                    gain = n_left * (e[left].mean() - e.mean()) ** 2 + (len(rows) - n_left) * (e[~left].mean() - e.mean()) ** 2
                    if best is None or gain > best[0]:
                        best = (gain, index, column, cut)
        if best is None or best[0] <= 0:
            break
        _, index, column, cut = best
        rows = leaves.pop(index)
        left = table[rows, column] <= cut
        leaves += [rows[left], rows[~left]]
    return leaves


def feature_table(model, states, by=None):
    """The region variables ``by`` (the model's by default) of each state as columns, and which rows
    have them all finite (a pose outside every hallway has no progress)."""
    from percver.errors import InputError

    by = tuple(by or model.region_variables)
    features = model.features(states)
    unknown = [name for name in by if name not in features]
    if unknown:
        raise InputError(f"cannot localise by {unknown}: the model offers {sorted(features)}")
    table = np.column_stack([np.asarray(features[name], dtype=float) for name in by])
    return by, table, np.all(np.isfinite(table), axis=1)
