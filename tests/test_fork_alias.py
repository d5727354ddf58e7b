"""Undecided conditions on different quantities whose Taylor models are equal (issue 24).

Two different quantities have equal models whenever each is only its remainder interval
(`sin(1000 x)` and `sin(1000 y)` on a wide cell, two `pv.uncertain(-1, 1)` parameters). The engine
once forced the second condition onto the first one's branch, so the runs that take mixed branches
were dropped and unsafe loops came out "verified". Each loop here has a run that violates its
property; none may be verified, whatever the splitting settings, and the falsifier must find the
run where one is simple to find.
"""

import numpy as np
import pytest

import percver as pv
from percver.networks import Layer, Network

X0 = (0.0031, 0.0131)  # sin(1000 x) takes both signs on it: x = 0.004 gives > 0, 0.009 gives < 0


def _verify(plant, safe, init, **options):
    return pv.verify(pv.ClosedLoop(plant, stages=[]), steps=1, safe=safe, init=init, progress=False, **options)


def _two_sines():
    x, y, c = pv.variables("x y c")
    plant = pv.Discrete({x: x, y: y, c: c + pv.where(pv.sin(1000 * x) <= 0, 1.0, 0.0) + pv.where(pv.sin(1000 * y) <= 0, 0.0, 1.0)})
    return plant, c <= 1.5, {"x": X0, "y": X0, "c": (0, 0)}


def _two_parameters():
    z = pv.variables("z")
    a, b = pv.uncertain(-1, 1), pv.uncertain(-1, 1)
    return pv.Discrete({z: z + pv.where(a <= 0, 1.0, 0.0) + pv.where(b <= 0, 0.0, 1.0)}), z <= 1.5, {"z": (0, 0.1)}


def _three_conditions():
    # c counts how many of three sines are <= 0 (x, y, w); all three at once is unsafe.
    x, y, w, c = pv.variables("x y w c")
    hits = sum(pv.where(pv.sin(1000 * s) <= 0, 1.0, 0.0) for s in (x, y, w))
    return pv.Discrete({x: x, y: y, w: w, c: c + hits}), c <= 2.5, {"x": X0, "y": X0, "w": X0, "c": (0, 0)}


def _nested():
    # The inner condition on y is asked only inside the outer branch on x: both must be explored.
    x, y, c = pv.variables("x y c")
    inner = pv.where(pv.sin(1000 * y) <= 0, 1.0, 0.0)
    plant = pv.Discrete({x: x, y: y, c: c + pv.where(pv.sin(1000 * x) <= 0, inner, 0.5 * inner)})
    return plant, c <= 0.75, {"x": X0, "y": X0, "c": (0, 0)}


def _saturated_networks():
    # Two different steep sigmoid networks of x and y: each output's model is about [0, 1].
    x, y, c = pv.variables("x y c")

    def steep(sign):
        return Network([Layer(np.array([[sign * 4000.0]]), np.array([-sign * 4000.0 * 0.0081]), "sigmoid")])

    loop = pv.ClosedLoop(
        pv.Discrete(
            {x: x, y: y, c: c + pv.where(pv.variables("sx") <= 0.5, 1.0, 0.0) + pv.where(pv.variables("sy") <= 0.5, 0.0, 1.0)},
            inputs=["sx", "sy"],
        ),
        stages=[pv.Stage(steep(1.0), inputs=[x], output="sx"), pv.Stage(steep(1.0), inputs=[y], output="sy")],
    )
    return loop, c <= 1.5, {"x": X0, "y": X0, "c": (0, 0)}


def _min_max_clip():
    # clip/min/max of aliasing operands: max(sin(1000 x), sin(1000 y)) <= 0 needs both <= 0.
    x, y, c = pv.variables("x y c")
    m = pv.maximum(pv.sin(1000 * x), pv.sin(1000 * y))
    k = pv.clip(pv.sin(1000 * x), -0.5, 0.5) - pv.clip(pv.sin(1000 * y), -0.5, 0.5)
    plant = pv.Discrete({x: x, y: y, c: c + pv.where(m <= 0, 1.0, 0.0) + pv.where(k >= 0.99, 1.0, 0.0)})
    return plant, c <= 0.5, {"x": X0, "y": X0, "c": (0, 0)}


def _run(case, **options):
    target, safe, init = case()
    if isinstance(target, pv.ClosedLoop):
        return pv.verify(target, steps=1, safe=safe, init=init, progress=False, **options)
    return _verify(target, safe, init, **options)


CASES = [_two_sines, _two_parameters, _three_conditions, _nested, _saturated_networks, _min_max_clip]


@pytest.mark.parametrize("case", CASES, ids=lambda f: f.__name__.strip("_"))
@pytest.mark.parametrize("options", [{}, {"max_splits": 0}, {"max_splits": 64}, {"falsify": 0}], ids=str)
def test_mixed_branches_are_never_verified_away(case, options):
    res = _run(case, **options)
    assert res.verdict != "verified", f"{case.__name__} verified with {options}: {[c.reason for c in res.cells]}"


@pytest.mark.parametrize("case", CASES, ids=lambda f: f.__name__.strip("_"))
def test_the_violating_run_exists(case):
    """The loops are unsafe (the tests above could not fail otherwise): a point violates."""
    target, safe, init = case()
    loop = target if isinstance(target, pv.ClosedLoop) else pv.ClosedLoop(target, stages=[])
    rng = np.random.default_rng(0)
    x0 = np.column_stack([rng.uniform(*init[s], 4000) for s in loop.states])
    params = {pid: rng.uniform(lo, hi, len(x0)) for pid, lo, hi in loop.parameters()}
    x1 = loop.simulate(x0, 1, parameters=params)[:, 1]
    margin = pv.evaluate(safe.margin(), dict(zip(loop.states, x1.T)))
    assert (margin > 0).any()


def test_falsifier_draws_uncertain_parameters_and_the_counterexample_replays():
    target, safe, init = _two_parameters()
    loop = pv.ClosedLoop(target, stages=[])
    res = pv.verify(loop, steps=1, safe=safe, init=init, progress=False)
    assert res.verdict == "falsified"
    cex = res.counterexample
    values = {p["value"] for p in cex.parameters}
    assert len(cex.parameters) == 2 and all(-1 <= v <= 1 for v in values)
    x0 = np.array([[cex.initial[s] for s in loop.states]])
    replay = loop.simulate(x0, 1, parameters=cex.parameter_values())
    np.testing.assert_array_equal(replay[0], np.array(cex.trajectory))
    assert replay[0, 1, 0] > 1.5
    # A counterexample survives the journal's JSON round trip with its parameters.
    again = pv.Result.from_json(res.to_json()).counterexample
    assert again.parameters == cex.parameters


def test_one_parameter_asked_twice_is_one_question():
    """The same parameter under two separately built conditions is the same quantity: both
    `where`s take one branch together, and the loop (safe for every value) verifies without
    splitting into the combinations no run takes."""
    z = pv.variables("z")
    a = pv.uncertain(-1, 1)
    plant = pv.Discrete({z: z + pv.where(a <= 0, 1.0, 0.0) + pv.where(a <= 0, 0.0, 1.0)})
    res = _verify(plant, z <= 1.5, {"z": (0, 0.1)})
    assert res.verdict == "verified"
    assert pv.bounds(pv.uncertain(-1, 1) - pv.uncertain(-1, 1), {}, method="interval")[1] >= 2 - 1e-12  # distinct
