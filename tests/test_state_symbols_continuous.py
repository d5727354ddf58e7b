"""Error symbols kept from period to period for a continuous plant (``state_symbols=True``): the
flowpipe carries them as variables of its own. Sound (every simulated run lies in the reach boxes
at every step) and tighter than boxing the remainders, on an oscillator whose ReLU controller
corrects its own earlier errors (TORA-like: the enclosure wraps without symbols)."""

import numpy as np
import pytest

import percver as pv


def loop():
    rng = np.random.default_rng(3)
    w1, w2 = rng.normal(0, 0.7, (16, 2)), rng.normal(0, 0.25, (1, 16))
    net = pv.Network([(w1, rng.normal(0, 0.1, 16), "relu"), (w2, np.zeros(1), "identity")])
    x, v, u = pv.variables("x v u")
    plant = pv.Continuous({x: v, v: -x + 0.1 * pv.sin(x) + u - 0.5 * v}, inputs=[u], period=0.5)
    return pv.ClosedLoop(plant, [pv.Stage(net, inputs=["x", "v"], output="u")])


INIT = {"x": (0.6, 0.65), "v": (-0.3, -0.25)}


@pytest.mark.parametrize("symbols", [False, True])
def test_reach_boxes_enclose_simulations(symbols):
    closed = loop()
    result = pv.verify(closed, INIT, steps=12, safe=pv.Box({"x": (-5, 5)}), order=3, max_splits=0, state_symbols=symbols, progress=False)
    cell = result.cells[0]
    assert result.verdict == "verified", cell.reason
    rng = np.random.default_rng(0)
    lo, hi = np.array([b[0] for b in INIT.values()]), np.array([b[1] for b in INIT.values()])
    x0 = np.vstack([lo + (hi - lo) * rng.uniform(size=(300, 2)), np.array(np.meshgrid(*zip(lo, hi))).reshape(2, -1).T])
    runs = closed.simulate(x0, 12)
    for k, box in enumerate(cell.boxes):
        b = np.array(box)
        assert np.all(runs[:, k] >= b[:, 0] - 1e-12) and np.all(runs[:, k] <= b[:, 1] + 1e-12), f"step {k}"


def test_symbols_are_tighter_at_the_end():
    widths = {}
    for symbols in (False, True):
        result = pv.verify(
            loop(), INIT, steps=12, safe=pv.Box({"x": (-5, 5)}), order=3, max_splits=0, state_symbols=symbols, progress=False
        )
        widths[symbols] = np.ptp(np.array(result.cells[0].boxes[-1]), axis=1).max()
    assert widths[True] < 0.8 * widths[False], widths
