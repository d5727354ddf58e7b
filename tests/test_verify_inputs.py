"""Bad input to closed-loop verification: clear errors (types from percver.errors) before any work
starts, and a warning for an initial set outside a stage's declared input range. (Wiring to an
unknown signal, a network's input count, missing init states and a property over a non-state are
covered in test_verify.py; these are the rest.)"""

import warnings

import numpy as np
import pytest

import percver as pv
from closed_loops import CONTROLLER, mountain_car
from percver.systems import InputRangeWarning

INIT = {"p": (-0.52, -0.5), "v": (0, 0)}


def verify_refused(loop, tmp_path, match, **kwargs):
    """pv.verify raises InputError matching ``match``, and no work started (no journal written)."""
    journal = tmp_path / "run.jsonl"
    with pytest.raises(pv.InputError, match=match):
        pv.verify(loop, journal=str(journal), progress=False, **{"init": INIT, "steps": 150, **kwargs})
    assert not journal.exists(), "the error must come before any cell is run or journaled"


def test_network_input_names_must_match_the_wired_signals():
    p, v, u = pv.variables("p v u")
    plant = pv.Discrete({p: p + 0.01 * u, v: v}, inputs=[u])
    named = pv.load_network(str(CONTROLLER)).with_input_names(["p", "v"])
    pv.ClosedLoop(plant, [pv.Stage(named, inputs=[p, v], output="u")])  # matching names: fine
    with pytest.raises(pv.InputError, match=r"takes inputs \(p, v\) but is wired to \(v, p\).*network's order"):
        pv.ClosedLoop(plant, [pv.Stage(named, inputs=[v, p], output="u")])
    with pytest.raises(pv.InputError, match=r"wired to \(v, p\)"):  # names kept through a stage's output map
        pv.ClosedLoop(plant, [pv.Stage(named, inputs=[v, p], output="u", scale=2.0)])
    q = pv.variables("q")
    other = pv.Discrete({q: q + 0.01 * u, v: v}, inputs=[u])
    with pytest.raises(pv.InputError, match=r"wired to \(q, v\).*with_input_names"):
        pv.ClosedLoop(other, [pv.Stage(named, inputs=[q, v], output="u")])
    # Unnamed inputs (in0, in1, ...) take any signal.
    pv.ClosedLoop(other, [pv.Stage(pv.load_network(str(CONTROLLER)), inputs=[q, v], output="u")])


def test_dimension_mismatches():
    p, v, u = pv.variables("p v u")
    plant = pv.Discrete({p: p + 0.01 * u, v: v}, inputs=[u])
    ctrl = pv.load_network(str(CONTROLLER))
    obs = pv.Stage([p, v, p * v], inputs=[p, v], output="obs")
    with pytest.raises(pv.InputError, match=r"takes 2 inputs but is wired to obs \(3\) = 3"):
        pv.ClosedLoop(plant, [obs, pv.Stage(ctrl, inputs=["obs"], output="u")])
    with pytest.raises(pv.InputError, match="has 1 outputs but scale has 3 values"):
        pv.Stage(ctrl, inputs=[p, v], output="u", scale=[1.0, 2.0, 3.0])
    with pytest.raises(pv.InputError, match="has 3 outputs but offset has 2 values"):
        pv.Stage([p, v, p * v], inputs=[p, v], output="obs", offset=[0.0, 1.0])
    # A vector signal used as a scalar: the message names its components.
    wide = pv.Stage([p, v], inputs=[p, v], output="u")
    with pytest.raises(pv.InputError, match=r"'u' is a vector of 2: use its components u_0 .. u_1"):
        pv.ClosedLoop(plant, [wide])
    loop, p, v, u = mountain_car()
    with pytest.raises(pv.InputError, match=r"unknown \['w'\]"):
        pv.verify(loop, init={**INIT, "w": (0, 1)}, steps=3, goal=p >= 0.45, progress=False)
    with pytest.raises(pv.InputError, match="interval for 'p'"):
        pv.verify(loop, init={"p": (1, 2, 3), "v": 0}, steps=3, goal=p >= 0.45, progress=False)


def test_property_over_unknown_or_non_state_variables(tmp_path):
    loop, p, v, u = mountain_car()
    x, r = pv.variables("x r")
    verify_refused(loop, tmp_path, r"goal 'x >= 1.0' uses \['x'\]", goal=[p >= 0.45, x >= 1])
    verify_refused(loop, tmp_path, r"safe .* uses \['u'\], which are not states", safe=u <= 1)
    verify_refused(loop, tmp_path, r"unsafe .* uses \['r'\]", unsafe=r <= 90)  # a reward that was not declared
    verify_refused(loop, tmp_path, "must be a condition", goal="p >= 0.45")


def test_bad_accumulators(tmp_path):
    loop, p, v, u = mountain_car()
    r, w = pv.variables("r w")
    verify_refused(
        loop, tmp_path, r"accumulator 'r' uses \['w'\], which are neither states nor stage outputs", reward={"r": w**2}, goal=r >= 0
    )
    verify_refused(loop, tmp_path, "accumulator 'v' has the name of an existing signal", reward={"v": u}, goal=p >= 0.45)
    verify_refused(loop, tmp_path, "must be an identifier", reward={"r 2": u}, goal=p >= 0.45)
    verify_refused(loop, tmp_path, r"give accumulators as \{name: expression\}", reward={}, goal=p >= 0.45)
    with pytest.raises(pv.ParseError):
        loop.with_accumulators({"r": "u^"})


def test_mixed_conjunction_is_strict_and_exact_elsewhere():
    """A goal list is one condition: min of the margins; with a strict member the whole is strict."""
    from percver.systems import condition

    p, r = pv.variables("p r")
    both = pv.all_of(p >= 0.45, r + 100 > 90).condition()
    pts = {"p": np.array([0.5, 0.5, 0.4, 0.45]), "r": np.array([-5.0, -11.0, -5.0, -5.0])}
    margin = pv.evaluate(both.margin(), pts)
    assert both.op == ">" and list(margin > 0) == [True, False, False, False]  # the last: p = 0.45 exactly
    same = pv.all_of([p >= 0.45, r >= -10]).condition()
    assert same.op == ">=" and list(pv.evaluate(same.margin(), pts) >= 0) == [True, False, False, True]
    assert str(condition("x^2 + y <= 1")) == "((x^2) + y) <= 1.0"
    with pytest.raises(pv.InputError, match="not one comparison"):
        condition("p == 1")


def test_initial_box_outside_a_declared_input_range_warns():
    p, v, u = pv.variables("p v u")
    plant = pv.Discrete({p: p + v, v: v + 0.001 * u}, inputs=[u])
    ctrl = pv.load_network(str(CONTROLLER))
    stage = pv.Stage(ctrl, inputs=[p, v], output="u", domain={p: (-1.2, 0.6), "v": (-0.07, 0.07)})
    loop = pv.ClosedLoop(plant, [stage])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pv.verify(loop, init={"p": (-0.5, -0.4), "v": (0, 0)}, steps=2, safe=p >= -2, progress=False)
    with pytest.warns(InputRangeWarning, match=r"initial v in \[0, 0.1\] leaves \[-0.07, 0.07\].*stage 'u'"):
        pv.verify(loop, init={"p": (-0.5, -0.4), "v": (0, 0.1)}, steps=2, safe=p >= -2, progress=False)
    with pytest.raises(pv.InputError, match="domain names 'x', which is not among its inputs"):
        pv.Stage(ctrl, inputs=[p, v], output="u", domain={"x": (0, 1)})
    with pytest.raises(pv.InputError, match="empty interval"):
        pv.Stage(ctrl, inputs=[p, v], output="u", domain={"p": (1, 0)})
    obs = pv.Stage([p, v], inputs=[p, v], output="obs")
    with pytest.raises(pv.InputError, match=r"domain= bounds scalar inputs only; \['obs'\]"):
        pv.ClosedLoop(plant, [obs, pv.Stage(ctrl, inputs=["obs"], output="u", domain={"obs": (0, 1)})])
