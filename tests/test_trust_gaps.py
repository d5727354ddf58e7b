"""Inputs that used to be accepted and then proved something else (issue 24, other trust gaps):
unknown activations, non-finite constants, flowpipe time gaps. Each feeds the bad input and
expects the clear error, or samples the behaviour that used to fail."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv
from percver import _core
from percver.errors import InputError, NetworkFormatError, ParseError
from percver.expr import as_expr

MODELS = Path(__file__).resolve().parents[1].parent / "shared" / "anchors" / "flowstar_models"


# ------------------------------------------------------------------------------ unknown activations


def test_core_network_refuses_an_unknown_activation():
    # the Rust IR is reachable without the Python reader: it must refuse, not fall back to identity
    layer = (np.ones((2, 3)), np.zeros(2), ["tanh", "swish"])
    with pytest.raises(NetworkFormatError, match=r"layer 1: .*'swish'.*sigmoid, tanh, relu or identity"):
        _core.Network([layer])


# ------------------------------------------------------------------------------ non-finite constants

x = pv.variables("x")


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan, np.float64("inf")])
@pytest.mark.parametrize(
    "build",
    [
        lambda v: x * v,
        lambda v: v + x,
        lambda v: x / v,
        lambda v: pv.minimum(x, v),
        lambda v: pv.where(x >= v, x, 0.0),
        lambda v: as_expr(v),
        lambda v: x**v,
        lambda v: pv.uncertain(0.0, v),
        lambda v: pv.uncertain(v, 1.0),
    ],
    ids=["mul", "radd", "div", "minimum", "where", "constant", "pow", "uncertain_hi", "uncertain_lo"],
)
def test_non_finite_constants_are_input_errors(build, value):
    # x * inf used to be bounded as [0, inf] on [0, 1] while evaluating to NaN at x = 0
    with pytest.raises(InputError, match=r"not a finite number|finite constant exponent"):
        build(value)


def test_reversed_uncertain_bounds_and_overflowing_literals_are_refused():
    with pytest.raises(InputError, match=r"lower bound 2 is above upper bound 1; swap them"):
        pv.uncertain(2.0, 1.0)
    with pytest.raises(ParseError, match=r"'1e400' overflows to infinity"):
        pv.parse("x * 1e400")


def test_finite_constants_still_bound_what_they_evaluate_to():
    # the check refuses only non-finite numbers: large finite ones keep bounds and floats in step
    e = x * 1e300 + pv.uncertain(-1.0, 1.0)
    lo, hi = pv.bounds(e, {"x": (0.0, 1.0)})
    values = pv.evaluate(x * 1e300, {"x": np.linspace(0.0, 1.0, 101)})
    assert np.all((lo <= values - 1.0) & (values + 1.0 <= hi))


# ------------------------------------------------------------------------------ flowpipe time tiling

# (model, shortened horizon, trajectories): Lorenz and Laub-Loomis had float gaps of 1e-18 to
# 4e-15 between one step's end and the next one's start
TILING = [("tb_lorenz", 1.0, 300), ("tb_laubloomis", 4.0, 200)]


@pytest.mark.parametrize(("model", "t_end", "count"), TILING, ids=[m for m, _, _ in TILING])
def test_flowpipe_contains_trajectories_at_every_step_boundary(model, t_end, count):
    spec = pv.formats.load_flowstar(str(MODELS / f"{model}.model"))
    fp = dataclasses.replace(spec, t_end=t_end).run()
    assert fp.time_reached == t_end
    # the steps tile [0, t_end]: each starts on the float where the previous one ends
    assert fp.times[0, 0] == 0.0 and fp.times[-1, 1] == t_end
    assert np.array_equal(fp.times[1:, 0], fp.times[:-1, 1])

    names = spec.variables
    rhs = [pv.parse(spec.odes[v]) for v in names]
    box = pv.Box.coerce(spec.init, names)
    points = box.sample(count, seed=3)
    points[:2] = [[b[i] for b in box.bounds] for i in range(2)]  # two corners
    n, d = points.shape

    def f(_t, flat):
        return pv.evaluate(rhs, dict(zip(names, flat.reshape(d, n)))).T.reshape(-1)

    sol = solve_ivp(f, (0.0, t_end), points.T.reshape(-1), method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    assert sol.success
    # every boundary, its float neighbours on both sides and the step midpoints
    boundaries = fp.times[:, 1]
    times = np.concatenate([[0.0], boundaries, np.nextafter(boundaries, 0.0), np.nextafter(boundaries[:-1], np.inf),
                            0.5 * (fp.times[:, 0] + fp.times[:, 1])])  # fmt: skip
    all_t = np.repeat(times, n)
    states = np.concatenate([sol.sol(t).reshape(d, n).T for t in times])
    tol = 1e-9  # the reference's own error at rtol = atol = 1e-12
    inside = fp.contains(all_t, states, tol=tol)
    assert inside.all(), f"{np.count_nonzero(~inside)} sampled states outside, first at t = {all_t[~inside][0]!r}"
    # not vacuous: past the horizon, or moved well outside the step boxes, states are not contained
    assert not fp.contains(np.full(n, np.nextafter(t_end, np.inf)), sol.sol(t_end).reshape(d, n).T).any()
    width = fp.array[:, :, 1].max(axis=0) - fp.array[:, :, 0].min(axis=0)
    assert not fp.contains(all_t, states + 2 * width).any()


def test_contains_checks_its_arguments():
    fp = pv.flowpipe({x: -x}, init={"x": (1.0, 1.1)}, t_end=0.1, step=0.01)
    with pytest.raises(InputError, match=r"one state of 1 values per time"):
        fp.contains([0.0, 0.05], [[1.0]])
