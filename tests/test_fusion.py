"""Fusing consecutive network stages: the fused network computes exactly what the stages did."""

import numpy as np
import pytest

import percver as pv
from percver.fusion import fuse
from percver.networks import Layer, Network


def _net(rng, n_in, widths, activation, name, scale=None, offset=None):
    layers = []
    for n_out in widths:
        layers.append(Layer(rng.normal(size=(n_out, n_in)), rng.normal(size=n_out), activation))
        n_in = n_out
    return Network(layers, scale=scale, offset=offset, name=name)


def _loop(rng):
    x, d, v = pv.variables("x d v")
    a = _net(rng, 2, [5, 3], "tanh", "a", scale=np.array([2.0, 0.5, 1.0]), offset=np.array([0.1, -0.2, 0.0]))
    b = _net(rng, 2, [4, 2], "sigmoid", "b")  # reads a[2] and v: a wiring that reorders and skips
    c = _net(rng, 4, [3, 1], "tanh", "c", scale=np.array([0.7]), offset=np.array([0.05]))
    plant = pv.Discrete({x: x + 0.1 * v, v: v + 0.05 * pv.variables("u") - 0.01 * pv.variables("b_1"), d: d}, inputs=["u", "b"])
    stages = [
        pv.Stage(a, inputs=[d, x], output="a"),
        pv.Stage([pv.variables("a_2") * 1.0], inputs=["a"], output="e"),  # an expression stage ends a run
        pv.Stage(b, inputs=["e", v], output="b"),
        pv.Stage(c, inputs=["b", d, "e"], output="u"),
    ]
    return pv.ClosedLoop(plant, stages)


def test_fused_stages_compute_what_the_stages_compute():
    rng = np.random.default_rng(3)
    loop = _loop(rng)
    reads = {n for e in loop.plant.update for n in e.variables()}
    fused, env = fuse(loop.env_names, loop.stage_inputs, loop.stages, reads)
    # a alone (followed by an expression), the expression, then b and c as one network.
    assert [type(f.component).__name__ for f in fused] == ["Network", "list", "Network"]
    assert env[: len(loop.states)] == loop.states
    assert "b_1" in env and "u" in env  # the plant reads both
    samples = rng.uniform(-1, 1, size=(500, len(loop.states)))
    for state in samples:
        # Reference: every stage on its own, in float, filling the original environment in order.
        env_values = list(state)
        for stage, inputs in zip(loop.stages, loop.stage_inputs):
            env_values += list(_apply(stage.component, [loop.env_names[i] for i in inputs], [env_values[i] for i in inputs]))
        values = dict(zip(loop.env_names, env_values))
        # Fused: the environment the fused stages build.
        got = dict(zip(loop.states, state))
        for f in fused:
            got.update(zip(f.outputs, _apply(f.component, [env[i] for i in f.inputs], [got[env[i]] for i in f.inputs])))
        for name in env:
            assert got[name] == pytest.approx(values[name], rel=1e-12, abs=1e-12), name


def _apply(component, names, args):
    if isinstance(component, Network):
        return component(np.array(args))
    return pv.evaluate(component, {n: [a] for n, a in zip(names, args)})[0]


def test_fused_loop_encloses_simulations():
    """The whole engine on the fused loop: simulated runs stay in the per-step boxes."""
    rng = np.random.default_rng(4)
    loop = _loop(rng)
    x, d, v = pv.variables("x d v")
    init = {"x": (0.1, 0.12), "d": (-0.3, -0.25), "v": (0.0, 0.01)}
    result = pv.verify(loop, init, steps=12, safe=[x <= 50], progress=False, falsify=4)
    cell = result.cells[0]
    assert cell.verdict == "verified", cell.reason
    starts = np.column_stack([rng.uniform(lo, hi, 1000) for lo, hi in (init[s] for s in loop.states)])
    runs = loop.simulate(starts, steps=12)
    for k, box in enumerate(cell.boxes):
        lo, hi = np.array(box).T
        states = runs[:, k, :]
        assert np.all((states >= lo - 1e-12) & (states <= hi + 1e-12)), f"step {k}"
