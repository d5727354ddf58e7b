"""Even powers and sums of squares are nonnegative by their form: sqrt and fractional powers of
them are defined on every box, although their enclosures (0 + 0 rounded down, a square's Taylor
model bounded term by term) dip below 0. Sampling: every float value lies in the enclosures."""

import numpy as np
import pytest

import percver as pv

vx, vy, w = pv.variables("vx vy w")

FORMS = {
    "norm": (pv.sqrt(vx**2 + vy**2), lambda a, b, c: np.sqrt(a**2 + b**2)),
    "power": ((vx * vx + vy**4) ** 0.5, lambda a, b, c: (a * a + b**4) ** 0.5),
    "nested": (pv.sqrt(pv.abs_(w) + pv.sqrt(vx**2) * pv.exp(vy)), lambda a, b, c: np.sqrt(np.abs(c) + np.sqrt(a**2) * np.exp(b))),
    "where": (pv.sqrt(pv.where(w >= 0, vx**2, vy**2 + 0.5)), lambda a, b, c: np.sqrt(np.where(c >= 0, a**2, b**2 + 0.5))),
    "margin": (
        pv.sqrt(vx**2 + vy**2) - 0.2 - 0.1 * pv.sqrt(w**2 + 1),
        lambda a, b, c: np.sqrt(a**2 + b**2) - 0.2 - 0.1 * np.sqrt(c**2 + 1),
    ),
}
BOXES = [
    {"vx": (-0.3, 0.3), "vy": (-0.2, 0.25), "w": (-1, 1)},
    {"vx": (0.0, 0.1), "vy": (0.0, 0.0), "w": (0.0, 0.0)},
    {"vx": (-1e-9, 1e-9), "vy": (-1e-9, 1e-9), "w": (-1e-9, 0)},
    {"vx": (0.3, 0.4), "vy": (0.1, 0.2), "w": (0.5, 2)},
]


@pytest.mark.parametrize("form", sorted(FORMS))
@pytest.mark.parametrize("method", ["interval", "taylor"])
def test_sqrt_of_a_nonnegative_form_encloses_its_samples(form, method):
    expr, f = FORMS[form]
    for k, box in enumerate(BOXES):
        lo, hi = pv.bounds(expr, box, method=method)
        pts = pv.Box(box).sample(4000, seed=k)
        corners = np.array(np.meshgrid(*[b for b in box.values()])).reshape(3, -1).T
        values = f(*np.vstack([pts, corners]).T)
        assert np.all((values >= lo) & (values <= hi)), (form, box, (lo, hi), values.min(), values.max())


def test_a_speed_limit_is_decided_from_step_0():
    """Docking's form sqrt(vx^2 + vy^2) <= limit, on a box around vx = vy = 0: the square's
    model dipped below 0 and the cell was unknown at step 0."""
    loop = pv.ClosedLoop(pv.Discrete({vx: 0.9 * vx - 0.1 * vy, vy: 0.1 * vx + 0.9 * vy}))
    init = {"vx": (-0.1, 0.1), "vy": (-0.1, 0.1)}
    res = pv.verify(loop, init=init, steps=20, safe=pv.sqrt(vx**2 + vy**2) <= 0.15, progress=False)
    assert res.verdict == "verified", res.cells[0].reason
    runs = loop.simulate(pv.Box(init).sample(2000, seed=1), 20)
    assert np.sqrt((runs**2).sum(axis=2)).max() <= 0.15
    boxes = np.asarray(res.cells[0].boxes)
    assert np.all((runs >= boxes[None, :, :, 0]) & (runs <= boxes[None, :, :, 1]))


def test_interval_enclosures_of_nonnegative_forms_stay_at_or_above_0():
    """0 + 0 rounded down is -5e-324: the sum of two squares' intervals reached below 0."""
    for k, box in enumerate(BOXES):
        for e in (vx**2 + vy**2, vx * vx + pv.abs_(w), (vx**2 + 1e-3) * pv.exp(w)):
            lo, hi = pv.bounds(e, box, method="interval")
            assert lo >= 0.0, (e, box, lo)
            values = pv.evaluate(e, dict(zip(box, pv.Box(box).sample(2000, seed=k).T)))
            assert np.all((values >= lo) & (values <= hi))
