"""Figures the package writes show what they claim (conftest checks every PNG a test writes for
blank axes; these tests make the figures no other test makes in this process)."""

import numpy as np
import pytest

import percver as pv
from figures import blank_axes
from percver.verify import Cell


def _cells(width: float) -> list:
    """Two verified cells whose per-step boxes follow a curve and are ``width`` wide."""
    steps = np.linspace(0.65, 0.8, 40)
    cells = []
    for offset in (0.0, 2 * width):
        boxes = [[(y + offset, y + offset + width)] for y in steps]
        cells.append(Cell({"y1": (0.65 + offset, 0.65 + offset + width)}, "verified", boxes=boxes))
    return cells


def test_result_plot_shows_bands_narrower_than_a_pixel(tmp_path):
    """examples/f1tenth.py wrote a blank verified_y1.png: 5e-5-wide bands drawn with linewidth 0."""
    result = pv.Result(["y1"], {"y1": (0.65, 0.6501)}, _cells(5e-5), 1.0)
    fig = result.plot("y1", tmp_path / "tube.png")
    assert not blank_axes(fig, tmp_path / "tube.png")


def test_blank_figures_are_caught(tmp_path):
    """The check itself: a figure whose data is invisible is reported."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.fill_between(np.arange(40), np.linspace(0, 1, 40), np.linspace(0, 1, 40) + 1e-5, linewidth=0, alpha=0.3)
    ax.set_title("tube")
    ax.grid(alpha=0.3)
    path = tmp_path / "blank.png"
    fig.canvas.print_png(str(path))  # the canvas directly: conftest's check on Figure.savefig would fail here
    assert blank_axes(fig, path) == ["tube"]
    plt.close(fig)


def test_flowpipe_plot_is_drawn(tmp_path):
    p, v = pv.variables("p v")
    fp = pv.flowpipe({p: v, v: -p}, init={"p": (1.0, 1.1), "v": (0.0, 0.1)}, t_end=1.0)
    fp.plot("p", "v", path=str(tmp_path / "fp.png"))


@pytest.mark.parametrize("verdict", ["verified", "unknown"])
def test_mountain_car_figures_are_drawn(tmp_path, verdict):
    """The demo's figure (reach tube, arrival, reward) and the coverage map, on a two-cell slice."""
    from percver.cases.mountain_car import verification

    result = verification.verify("contrast", (-0.5, -0.4995), "ours", delta_c=(1.5, 1.6), workers=2, progress=False)
    assert result.verdict == "verified"
    if verdict == "unknown":  # the figure must also tell an open cell apart
        result.cells[0].verdict = "unknown"
        result.cells[0].reason = "step 90: goal 'p >= 0.45' holds on part of the set only since step 89"
    loop = verification.closed_loop("contrast", "ours")
    verification.plot_tube(result, tmp_path / "tube.png", loop, samples=10)
    verification.plot_coverage(result, tmp_path / "coverage.png")
    title = verification.proven(result)
    assert "p0 in [-0.5, -0.4995]" in title and "contrast dc in [1.5, 1.6]" in title and "within 150 steps" in title
    assert "reward > 90" in title and verdict.upper() in title
