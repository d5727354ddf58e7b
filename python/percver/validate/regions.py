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


def feature_table(model, evaluation, by=None):
    """The region variables ``by`` (the model's by default; the evaluation's row features, such as
    ``step_in_run``, may be named too) of each row as columns, and which rows have them all
    finite (a pose outside every hallway has no progress)."""
    from percver.errors import InputError

    by = tuple(by or model.region_variables)
    features = {**model.features(evaluation.states), **evaluation.row_features}
    unknown = [name for name in by if name not in features]
    if unknown:
        raise InputError(f"cannot localise by {unknown}: the model offers {sorted(features)}")
    table = np.column_stack([np.asarray(features[name], dtype=float) for name in by])
    return by, table, np.all(np.isfinite(table), axis=1)


# A missing-data pattern is reported when its rate is this many times the rate elsewhere, with
# this many standard errors.
MISSING_RATIO = 2.0
MISSING_Z = 4.0


def missing_pattern(model, predicted, measured, evaluation=None):
    """Where lost echoes (rays predicted to echo that read the range limit) are not uniform: the
    set of entries, by predicted range or, given the rows' ``evaluation``, angle of incidence on
    the wall or time in the run (above or below a cut), or by ray, whose loss rate stands out
    most from the rest; None when losses look uniform, are too few, or the model has no range
    limit. A dict with ``where``, ``rate``, ``rate_elsewhere``, ``share`` (of the losses)."""
    if not hasattr(model, "range_limit"):
        return None
    limit = model.range_limit()
    echoing = predicted < limit * 0.98
    lost = (measured >= limit * (1 - 1e-9)) & echoing
    n, k = int(echoing.sum()), int(lost.sum())
    if k < 10 or k == n:
        return None
    rate = k / n
    ranges, lost_flat = predicted[echoing], lost[echoing]
    rays = np.broadcast_to(np.arange(predicted.shape[1]), predicted.shape)[echoing]
    measures = [("predicted range", " m", ranges)]
    if evaluation is not None and hasattr(model, "hits"):
        with np.errstate(invalid="ignore"):
            incidence = np.degrees(np.arccos(np.clip(model.hits(evaluation.states).cos_incidence, 0.0, 1.0)))
        measures.append(("incidence", " deg", incidence[echoing]))
    if evaluation is not None and "time_in_run" in evaluation.row_features:
        time = np.broadcast_to(np.asarray(evaluation.row_features["time_in_run"], dtype=float)[:, None], predicted.shape)
        measures.append(("time in run", "", time[echoing]))
    candidates = []
    for label, unit, values in measures:
        known = np.isfinite(values)
        for cut in np.unique(np.quantile(values[known], np.linspace(0.1, 0.9, 9))):
            candidates += [
                (f"{label} >= {cut:.3g} {unit}", known & (values >= cut)),
                (f"{label} <= {cut:.3g} {unit}", known & (values <= cut)),
            ]
    names = getattr(model, "measurement_names", None)
    candidates += [(f"ray {names[j] if names else j}", rays == j) for j in range(predicted.shape[1])]
    best = None
    for where, inside in candidates:
        n_in = int(inside.sum())
        if n_in < 10 or n - n_in < 10:
            continue
        k_in = int(lost_flat[inside].sum())
        rate_in, rate_out = k_in / n_in, (k - k_in) / (n - n_in)
        z = (rate_in - rate_out) / np.sqrt(rate * (1 - rate) * (1 / n_in + 1 / (n - n_in)))
        if best is None or z > best[0]:
            best = (z, where, rate_in, rate_out, k_in / k)
    if best is None or best[0] < MISSING_Z or best[2] < MISSING_RATIO * best[3]:
        return None
    z, where, rate_in, rate_out, share = best
    return {
        "kind": "missing",
        "where": f"lost echoes: {where} ({rate_in:.1%} lost there, {rate_out:.1%} elsewhere)",
        "rate": rate_in,
        "rate_elsewhere": rate_out,
        "share": share,
    }
