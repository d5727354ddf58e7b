"""PNG plots and a self-contained HTML page (one directory, relative links) for reports and diagnoses.

Figures are built with ``matplotlib.figure.Figure`` directly, so no pyplot state or display
backend is touched.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np


# Rows of the unexplained table: an image may have hundreds of pixels left over.
UNEXPLAINED_ROWS = 30


def _figure(width=7.0, height=4.0):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def _save(figure, path):
    if path is not None:
        figure.savefig(path)
    return figure


def residual_map(report, path=None, where=None):
    """Error over the region variables (mean per bin), with the significant regions outlined."""
    where = where or report.where()
    features = report.features()
    figure = _figure()
    axes = figure.add_subplot()
    errors = np.sqrt(report.row_errors)
    names = where.variables
    first = np.asarray(features[names[0]], dtype=float)
    known = np.isfinite(first)
    if len(names) >= 2:
        second = np.asarray(features[names[1]], dtype=float)
        known &= np.isfinite(second)
        # Bins at quantiles of the data, so that sparse corners of state space do not leave the map empty.
        xe, ye = (np.unique(np.quantile(v[known], np.linspace(0, 1, n + 1))) for v, n in ((first, 24), (second, 8)))
        total, xe, ye = np.histogram2d(first[known], second[known], bins=(xe, ye), weights=errors[known])
        count, _, _ = np.histogram2d(first[known], second[known], bins=(xe, ye))
        with np.errstate(invalid="ignore"):
            mean = total / count
        from matplotlib import colormaps

        cmap = colormaps["magma"].with_extremes(bad="#dddddd")  # grey: no samples there
        image = axes.pcolormesh(xe, ye, np.ma.masked_invalid(mean.T), cmap=cmap, shading="flat")
        figure.colorbar(image, ax=axes, label="RMS error per sample")
        from matplotlib.patches import Rectangle

        for region in where.significant_regions:
            if names[0] not in region.bounds or names[1] not in region.bounds:
                continue  # a region of other variables (the first step of each run)
            (x0, x1), (y0, y1) = region.bounds[names[0]], region.bounds[names[1]]
            axes.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="cyan", linewidth=2))
            axes.text(x0, y1, f"{region.share:.0%}", color="cyan", va="bottom")
        axes.set_ylabel(names[1])
    else:
        total, edges = np.histogram(first[known], bins=30, weights=errors[known])
        count, _ = np.histogram(first[known], bins=edges)
        with np.errstate(invalid="ignore"):
            axes.stairs(total / count, edges, fill=True)
        axes.set_ylabel("RMS error per sample")
    axes.set_xlabel(names[0])
    axes.set_title("where the model fails")
    return _save(figure, path)


def dimension_errors(report, path=None):
    """RMS residual per measured dimension (a pixel map for images)."""
    model = report.model
    values = np.array(list(report.per_dimension.values()))
    figure = _figure()
    axes = figure.add_subplot()
    if model.kind == "image":
        image = axes.imshow(values.reshape(model.shape), cmap="magma")
        figure.colorbar(image, ax=axes, label="RMS residual")
    else:
        axes.bar(np.arange(len(values)), values, color="tab:red")
        labels = list(report.per_dimension)
        step = max(1, len(labels) // 12)
        axes.set_xticks(np.arange(len(labels))[::step], labels[::step], rotation=45, ha="right")
        axes.set_ylabel("RMS residual")
    axes.set_title("error per measured dimension")
    return _save(figure, path)


def worst_examples(report, path=None, count=4):
    """Measured vs predicted at the rows with the largest error."""
    model = report.model
    worst = np.argsort(report.row_errors)[::-1][:count]
    measured, predicted = report.evaluation.measured, report.predicted
    if model.kind == "image":
        figure = _figure(7.0, 1.8 * len(worst))
        grid = figure.subplots(len(worst), 3, squeeze=False)
        for row, i in zip(grid, worst):
            for axes, values, title in zip(
                row, (measured[i], predicted[i], measured[i] - predicted[i]), ("measured", "predicted", "residual")
            ):
                axes.imshow(values.reshape(model.shape), cmap="gray" if title != "residual" else "coolwarm")
                axes.set_title(f"row {report.evaluation.rows[i]}: {title}", fontsize=8)
                axes.axis("off")
        return _save(figure, path)
    figure = _figure(7.0, 2.0 * len(worst))
    grid = figure.subplots(len(worst), 1, squeeze=False)[:, 0]
    x = model.lidar.angles_deg if model.kind == "lidar" else np.arange(measured.shape[1])
    for axes, i in zip(grid, worst):
        axes.plot(x, measured[i], "o-", label="measured", markersize=3)
        axes.plot(x, predicted[i], "s--", label="predicted", markersize=3)
        state = ", ".join(_state(n, v) for n, v in zip(model.state_names, report.evaluation.states[i]))
        axes.set_title(f"row {report.evaluation.rows[i]}: {state}", fontsize=8)
        axes.legend(fontsize=7)
    grid[-1].set_xlabel("ray angle (deg)" if model.kind == "lidar" else "dimension")
    return _save(figure, path)


def _state(name, value) -> str:
    """A state for a title; angles (theta, heading in radians) in degrees, as ray angles are."""
    if name in ("theta", "heading", "yaw", "psi"):
        return f"{name}={np.degrees(value):.3g} deg"
    return f"{name}={value:.3g}"


def error_fall(diagnosis, path=None):
    """The error after each added effect."""
    labels = ["baseline"] + [f"+ {s.effect}" for s in diagnosis.steps]
    values = [diagnosis.baseline_error] + [s.error_after for s in diagnosis.steps]
    figure = _figure()
    axes = figure.add_subplot()
    axes.plot(range(len(values)), values, "o-", color="tab:blue")
    for i, v in enumerate(values):
        axes.annotate(f"{v:.3g}", (i, v), textcoords="offset points", xytext=(0, 6), ha="center", fontsize=8)
    axes.set_xticks(range(len(values)), labels, rotation=20, ha="right")
    axes.set_ylabel(f"{diagnosis.final.metric} ({_short_unit(diagnosis.final)})")
    axes.set_ylim(bottom=0)
    axes.set_title("error fall")
    return _save(figure, path)


def _short_unit(report) -> str:
    return report.unit.split(":")[0]


# ------------------------------------------------------------------------------ pages
def _table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _cell(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.4g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}={_cell(v)}" for k, v in value.items())
    return str(value)


_STYLE = (
    "body{font-family:sans-serif;max-width:960px;margin:2em auto;color:#222}"
    "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;font-size:90%}"
    "th{background:#eee}img{max-width:100%}"
)


def _page(directory, title, parts) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    page = directory / "index.html"
    body = "\n".join(parts)
    page.write_text(
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>\n{body}\n</body></html>\n"
    )
    return page


def _report_parts(report, directory, prefix) -> list:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    where = report.where()
    plots = {
        f"{prefix}residual_map.png": residual_map,
        f"{prefix}dimensions.png": dimension_errors,
        f"{prefix}worst.png": worst_examples,
    }
    for name, draw in plots.items():
        draw(report, directory / name)
    errors = {"rmse": report.rmse, "mae": report.mae, "max": report.max_error}
    summary = [
        ("model", report.model.describe()),
        ("rows", len(report.evaluation)),
        ("unit of the errors", report.unit),
        (f"error ({report.metric}, the ranking's measure)", report.error),
    ]
    summary += [(name, value) for name, value in errors.items() if name != report.metric]
    summary += list(report.downstream.items())
    parts = [
        _table(("quantity", "value"), summary),
        "<h3>Where the error is</h3>",
        f"<img src='{prefix}residual_map.png' alt='residual map'>",
        _table(
            ("share", "lift", "samples", "region", "significant"),
            [(f"{r.share:.1%}", r.lift, r.count, r.describe(), "yes" if r.significant else "") for r in where.regions],
        ),
        f"<img src='{prefix}dimensions.png' alt='error per dimension'>",
        _table(
            ("share", "rms (the dimension's units)", "dimension", "significant"),
            [(f"{d.share:.1%}", d.rmse, d.name, "yes" if d.significant else "") for d in where.dimensions[:12]],
        ),
        "<h3>Worst samples</h3>",
        f"<img src='{prefix}worst.png' alt='worst samples'>",
    ]
    ranking = report.explained_ranking()
    if ranking is not None:
        parts += ["<h3>Candidate effects (held-out)</h3>", _ranking_table(ranking)]
    return parts


def _ranking_table(ranking, added=None) -> str:
    return _table(
        ("effect", "gain", "95% interval", "claimed", "parameters", "physical cause"),
        [
            (c.name, c.gain, f"[{c.ci[0]:.3f}, {c.ci[1]:.3f}]", verdict, c.params, c.cause)
            for c, verdict in zip(ranking, ranking.verdicts(added))
        ],
    )


def write_report(report, directory) -> Path:
    return _page(directory, "percver model validation", _report_parts(report, directory, ""))


def _learned_parts(diagnosis, directory) -> list:
    """The learned noise model's held-out figures, and its files (ONNX and parameters) when it was kept."""
    attempt = diagnosis.learned
    if attempt is None:
        return []
    rows = [
        ("kind", f"learned_{attempt.kind}"),
        ("kept", "yes" if attempt.claimed else "no"),
        ("held-out gain", f"{attempt.gain:.1%} [{attempt.ci[0]:.1%}, {attempt.ci[1]:.1%}]"),
        ("held-out rows", attempt.held_out_rows),
        ("held-out error before", attempt.held_out_error_before),
        ("held-out error after", attempt.held_out_error_after),
    ]
    learned = getattr(diagnosis.final_model, "learned", None)
    if learned is not None:
        rows += [("files", ", ".join(path.name for path in learned.save(directory)))]
    return ["<h3>Learned noise model</h3>", _table(("quantity", "value"), rows)]


def write_diagnosis(diagnosis, directory) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    error_fall(diagnosis, directory / "error_fall.png")
    steps = [
        (i, s.effect, s.params, s.error_before, s.error_after, f"{s.explained_fraction:.1%}") for i, s in enumerate(diagnosis.steps, 1)
    ]
    parts = [
        "<h2>Error fall</h2>",
        "<img src='error_fall.png' alt='error fall'>",
        _table(("step", "effect", "parameters", "error before", "error after", "held-out gain"), steps),
    ]
    parts += _learned_parts(diagnosis, directory)
    if diagnosis.unexplained:
        shown = diagnosis.unexplained[:UNEXPLAINED_ROWS]
        parts += [
            "<h3>Still unexplained</h3>",
            _table(("kind", "where", "share"), [(u["kind"], u["where"], f"{u['share']:.1%}") for u in shown]),
        ]
        if len(diagnosis.unexplained) > len(shown):
            parts.append(f"<p>... and {len(diagnosis.unexplained) - len(shown)} more (see the JSON output)</p>")
    if diagnosis.rankings:
        parts += [
            "<h3>First ranking of candidate effects</h3>",
            "<p>added: in the final model; stand-in: helps alone, but another added effect explains the same error</p>",
            _ranking_table(diagnosis.rankings[0], diagnosis.effects),
        ]
    parts += ["<h2>Baseline model</h2>"] + _report_parts(diagnosis.baseline, directory, "baseline_")
    parts += ["<h2>Final model</h2>"] + _report_parts(diagnosis.final, directory, "final_")
    return _page(directory, "percver model diagnosis", parts)
