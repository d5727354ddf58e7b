"""The cheapest ARCH-COMP AINNCS examples end to end (examples/archcomp/): the verdict is the one
JuliaReach's repeatability package asserts, and a falsification's counterexample replays in a
float simulation of the loop. The rest run in bench/archcomp.py."""

import sys
from pathlib import Path

import pytest

import percver as pv

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "archcomp"
sys.path.insert(0, str(EXAMPLES))

from _common import MODELS, replays

pytestmark = pytest.mark.skipif(not MODELS.is_dir(), reason="the ARCH-COMP package is not in ../shared/data/archcomp2024")


@pytest.mark.parametrize(
    "name, variant",
    [
        ("inverted_pendulum", ""),
        ("acc", "relu"),
        ("tora", "relutanh"),
        ("inverted_two_link_pendulum", "more_robust"),
        ("airplane", ""),
        ("vertical_cas", "-25.5"),
    ],
)
def test_verdict_is_juliareachs(name, variant):
    bench = __import__(name)
    loop, kwargs = bench.problem(variant)
    result = pv.verify(loop, progress=False, **kwargs)
    assert result.verdict == bench.VARIANTS[variant], [c.reason for c in result.cells if c.verdict != "verified"][:3]
    if result.verdict == "falsified":
        assert replays(loop, result.counterexample, kwargs)


@pytest.mark.parametrize("corner", [0, -1])
def test_unicycle_cell_verifies_and_holds_simulated_runs(corner):
    """A corner cell of the unicycle's grid (the full benchmark is 84 of them, bench/archcomp.py)
    verifies with the example's settings, and 300 simulated runs from it, disturbance included,
    lie in its reach box at every one of the 50 steps."""
    import numpy as np

    bench = __import__("unicycle")
    loop, kwargs = bench.problem("")
    init, split = kwargs.pop("init"), kwargs.pop("split")
    cell = {}
    for name, (lo, hi) in init.items():
        width = (hi - lo) / split.get(name, 1)
        start = lo if corner == 0 else hi - width
        cell[name] = (start, start + width)
    result = pv.verify(loop, init=cell, splitter=pv.Grid({}), progress=False, **kwargs)
    assert result.verdict == "verified", [c.reason for c in result.cells]
    (only,) = result.cells
    boxes = np.asarray(only.boxes)
    assert boxes.shape[0] == kwargs["steps"] + 1
    lo, hi = np.array([cell[s] for s in loop.states]).T
    runs = loop.simulate(np.random.default_rng(7).uniform(lo, hi, size=(300, len(lo))), kwargs["steps"])
    assert np.all(runs >= boxes[None, :, :, 0] - 1e-12) and np.all(runs <= boxes[None, :, :, 1] + 1e-12)
