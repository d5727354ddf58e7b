"""pv.sign and pv.abs: float values equal numpy's, and interval and Taylor-model bounds over
boxes enclose the values at many sampled points (the effects' expression forms rely on both)."""

import numpy as np
import pytest

import percver as pv

x, y = pv.variables("x y")

CASES = [
    ("sign(x)", pv.sign(x), lambda a, b: np.sign(a)),
    ("abs(x)", pv.abs(x), lambda a, b: np.abs(a)),
    ("sign(x - 0.3 y)", pv.sign(x - 0.3 * y), lambda a, b: np.sign(a - 0.3 * b)),
    ("abs(x y - 0.1)", pv.abs(x * y - 0.1), lambda a, b: np.abs(a * b - 0.1)),
    ("sign(sin x) abs(y)", pv.sign(pv.sin(x)) * pv.abs(y), lambda a, b: np.sign(np.sin(a)) * np.abs(b)),
    # Coulomb friction written with sign and abs, as a user would.
    ("friction", pv.sign(y) * pv.maximum(pv.abs(y) - 0.2, 0.0), lambda a, b: np.sign(b) * np.maximum(np.abs(b) - 0.2, 0)),
]


@pytest.mark.parametrize("name, expr, reference", CASES, ids=[c[0] for c in CASES])
def test_float_values_equal_numpy(name, expr, reference):
    rng = np.random.default_rng(1)
    a, b = rng.uniform(-2, 2, 500), rng.uniform(-2, 2, 500)
    a[:50] = 0.0  # sign(0) = 0
    np.testing.assert_allclose(pv.evaluate(expr, {"x": a, "y": b}), reference(a, b), atol=1e-12)


@pytest.mark.parametrize("method", ["interval", "taylor"])
@pytest.mark.parametrize("name, expr, reference", CASES, ids=[c[0] for c in CASES])
def test_bounds_enclose_samples(name, expr, reference, method):
    rng = np.random.default_rng(2)
    for _ in range(40):
        centre, width = rng.uniform(-1.5, 1.5, 2), rng.choice([1e-6, 0.01, 0.3, 2.0], 2)
        box = {"x": (centre[0] - width[0] / 2, centre[0] + width[0] / 2), "y": (centre[1] - width[1] / 2, centre[1] + width[1] / 2)}
        lo, hi = pv.bounds(expr, box, method=method)
        a = np.concatenate([rng.uniform(*box["x"], 300), list(box["x"])])
        b = np.concatenate([rng.uniform(*box["y"], 300), list(box["y"])])
        values = reference(a, b)
        assert np.all(values >= lo) and np.all(values <= hi), (name, box, (lo, hi), values.min(), values.max())


def test_sign_is_exact_on_one_side_and_hull_across_zero():
    for method in ("interval", "taylor"):
        for box, (a, b) in [((0.1, 0.5), (1, 1)), ((-0.5, -0.1), (-1, -1)), ((-0.5, 0.1), (-1, 1))]:
            lo, hi = pv.bounds(pv.sign(x), {"x": box}, method=method)
            assert lo <= a and b <= hi and lo == pytest.approx(a, abs=1e-12) and hi == pytest.approx(b, abs=1e-12)
        lo, hi = pv.bounds(pv.abs(x), {"x": (-0.5, 0.1)}, method=method)
        assert lo <= 0.0 and 0.5 <= hi <= 0.5 + 1e-9
