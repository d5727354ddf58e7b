"""Flow* hybrid models of our own (examples/flowstar), read by pv.formats.load_flowstar and run with Taylor models
carried through the jumps (and boxed at the jumps, for comparison): thousands of runs simulated
in floats by scipy (DOP853, tight tolerances, the guards as events), written from the physics
and not from the parsed model, must lie in the computed step boxes at their times and in the
boxes at the horizon."""

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "flowstar"


def event(g, direction):
    def f(_t, y):
        return g(y)

    f.terminal, f.direction = True, direction
    return f


def simulate(x0: np.ndarray, t_end: float, modes: dict, start: str, times: np.ndarray, rng) -> tuple:
    """Runs of an automaton given in plain Python: ``modes[m] = (rhs, [(guard event, direction,
    target, reset)])``; a guard's event may be drawn anew at each jump (``g(rng)`` gives the event
    function: nondeterministic switching points). Returns states (N, T, n), modes (N, T) at
    ``times`` and the states at ``t_end``."""
    states = np.empty((len(x0), len(times), x0.shape[1]))
    where = np.empty((len(x0), len(times)), dtype=object)
    finals = np.empty_like(x0)
    for r, y in enumerate(x0):
        t, mode, y = 0.0, start, np.array(y, float)
        while True:
            rhs, jumps = modes[mode]
            drawn = [(make(rng), direction, target, reset) for make, direction, target, reset in jumps]
            sol = solve_ivp(
                lambda _t, z: rhs(z),
                (t, t_end),
                y,
                method="DOP853",
                rtol=1e-12,
                atol=1e-13,
                events=[event(g, d) for g, d, _, _ in drawn],
                dense_output=True,
            )
            end = sol.t[-1]
            inside = (times >= t) & (times <= end)
            states[r, inside] = sol.sol(times[inside]).T
            where[r, inside] = mode
            if sol.status != 1:
                finals[r] = sol.y[:, -1]
                break
            k = next(i for i, e in enumerate(sol.t_events) if len(e))
            _, _, mode, reset = drawn[k]
            t, y = end, reset(sol.y[:, -1])
    return states, where, finals


def check(run, times, states, where, finals, names):
    flat = states.reshape(-1, states.shape[2])
    ok = run.contains(np.repeat(times[None, :], len(states), 0).reshape(-1), flat, where.reshape(-1), tol=1e-9)
    assert ok.all(), f"{(~ok).sum()} sampled states outside the step boxes, e.g. {flat[~ok][:3]}"
    box = run.final_box()
    lo, hi = np.array([box[v][0] for v in names]), np.array([box[v][1] for v in names])
    assert ((finals >= lo - 1e-9) & (finals <= hi + 1e-9)).all(), (finals.min(0), finals.max(0), box)
    return hi - lo


@pytest.mark.parametrize("jumps", ["taylor", "box"])
def test_bouncing_ball(jumps):
    path = str(EXAMPLES / "bouncing_ball.model")
    run = pv.formats.load_flowstar(path).run(jumps=jumps)
    assert run.failure is None and run.jumps == jumps
    rng = np.random.default_rng(1)
    x0 = np.column_stack([rng.uniform(1.0, 1.1, 1000), np.zeros(1000)])
    x0[:2, 0] = 1.0, 1.1
    floor = (lambda _rng: lambda y: y[0], -1, "fly", lambda y: np.array([0.0, -0.8 * y[1]]))
    times = np.linspace(0, 1.5, 61)
    states, where, finals = simulate(x0, 1.5, {"fly": (lambda y: [y[1], -9.81], [floor])}, "fly", times, rng)
    assert (finals[:, 1] < 0).any() and (finals[:, 1] > 0).any(), "some runs have bounced twice by the horizon"
    widths = check(run, times, states, where, finals, ["x", "y"])
    assert widths[0] < 1.0 and widths[1] < 1.5, widths  # the sampled spread is about 0.12 and 0.8


def test_thermostat_switching_anywhere_in_its_guards():
    # Each jump may fire anywhere between its guard and the invariant: the runs draw the point.
    path = str(EXAMPLES / "thermostat.model")
    run = pv.formats.load_flowstar(path).run()
    assert run.failure is None
    rng = np.random.default_rng(2)
    x0 = rng.uniform(18.5, 19.0, (200, 1))
    up = (lambda rng: (lambda c: lambda y: y[0] - c)(rng.uniform(21, 22)), 1, "off", np.array)
    down = (lambda rng: (lambda c: lambda y: y[0] - c)(rng.uniform(18, 19)), -1, "on", np.array)
    automaton = {"on": (lambda y: [-0.5 * y[0] + 15], [up]), "off": (lambda y: [-0.5 * y[0]], [down])}
    times = np.linspace(0, 2.0, 41)
    states, where, finals = simulate(x0, 2.0, automaton, "on", times, rng)
    assert set(where[:, -1]) == {"on", "off"}
    check(run, times, states, where, finals, ["x"])
    assert {m for m, _ in run.finals} == {"on", "off"}


@pytest.mark.parametrize("jumps", ["taylor", "box"])
def test_two_nonlinear_modes(jumps):
    path = str(EXAMPLES / "two_modes.model")
    run = pv.formats.load_flowstar(path).run(jumps=jumps)
    assert run.failure is None
    rng = np.random.default_rng(3)
    x0 = rng.uniform([0.9, 0.9], [1.0, 1.0], (1000, 2))
    x0[:4] = [[0.9, 0.9], [0.9, 1.0], [1.0, 0.9], [1.0, 1.0]]
    cross = (lambda _rng: lambda y: y[0] - 1.2, 1, "damped", lambda y: np.array([y[0], 0.5 * y[1]]))
    automaton = {
        "vdp": (lambda y: [y[1], (1 - y[0] ** 2) * y[1] - y[0]], [cross]),
        "damped": (lambda y: [y[1], -np.sin(y[0]) - 0.5 * y[1]], []),
    }
    times = np.linspace(0, 2.0, 81)
    states, where, finals = simulate(x0, 2.0, automaton, "vdp", times, rng)
    assert (where[:, -1] == "damped").all()
    check(run, times, states, where, finals, ["x", "y"])


def test_taylor_models_through_jumps_are_tighter_than_boxes():
    path = str(EXAMPLES / "two_modes.model")
    spec = pv.formats.load_flowstar(path)
    widths = {j: sum(hi - lo for lo, hi in list(spec.run(jumps=j).final_box().values())[:2]) for j in ("taylor", "box")}
    assert widths["taylor"] < widths["box"], widths


OSCILLATORS = 14


def wide_model(path: Path) -> Path:
    """14 oscillators x'' = -k x with their stiffness k as a variable (42 variables and a clock):
    at c = 0.5 every velocity is reset to -v / 2 and damping starts. Uncertain are every x and
    three k, more than the symbols of a space at order 5 that wide (the rest are intervals)."""
    names = [f"{v}{i}" for i in range(OSCILLATORS) for v in "xvk"]

    def flow(damping: str) -> str:
        return "\n".join(f"    x{i}' = v{i}\n    v{i}' = -k{i} * x{i}{damping.format(i=i)}\n    k{i}' = 0" for i in range(OSCILLATORS))

    init = "\n".join(
        f"   x{i} in [{1 + 0.01 * i}, {1.05 + 0.01 * i}]\n   v{i} in [0, 0]\n   k{i} in "
        + ("[0.9, 1.1]" if i < 3 else f"[{1 + 0.1 * i}, {1 + 0.1 * i}]")
        for i in range(OSCILLATORS)
    )
    resets = " ".join(f"v{i}' := -0.5 * v{i}" for i in range(OSCILLATORS))
    path.write_text(
        f"""hybrid reachability
{{
 state var {", ".join(names)}, c
 setting
 {{
  adaptive steps {{ min 1e-4, max 0.05 }}
  time 1.0
  remainder estimation 1e-6
  identity precondition
  fixed orders 5
  cutoff 1e-14
  max jumps 1
 }}
 modes
 {{
  free
  {{
   nonpoly ode
   {{
{flow("")}
    c' = 1
   }}
   inv {{ c <= 0.5 }}
  }}
  damped
  {{
   nonpoly ode
   {{
{flow(" - 0.3 * v{i}")}
    c' = 1
   }}
  }}
 }}
 jumps
 {{
  free -> damped
  guard {{ c >= 0.5 }}
  reset {{ {resets} c' := 0 }}
  interval aggregation
 }}
 init
 {{
  free
  {{
{init}
   c in [0, 0]
  }}
 }}
}}
"""
    )
    return path


def test_a_wide_automaton_runs_group_by_group(tmp_path):
    spec = pv.formats.load_flowstar(str(wide_model(tmp_path / "wide.model")))
    assert len(spec.variables) == 3 * OSCILLATORS + 1
    run = spec.run()
    assert run.failure is None
    rng = np.random.default_rng(4)
    lo = np.array([spec.init[v][0] for v in spec.variables])
    hi = np.array([spec.init[v][1] for v in spec.variables])
    x0 = rng.uniform(lo, hi, (300, len(lo)))
    x0[:2] = lo, hi
    k = slice(2, 3 * OSCILLATORS, 3)

    def moving(damping):
        def rhs(y):
            out = np.zeros_like(y)
            out[0 : 3 * OSCILLATORS : 3] = y[1 : 3 * OSCILLATORS : 3]
            out[1 : 3 * OSCILLATORS : 3] = -y[k] * y[0 : 3 * OSCILLATORS : 3] - damping * y[1 : 3 * OSCILLATORS : 3]
            out[-1] = 1.0
            return out

        return rhs

    def reset(y):
        y = y.copy()
        y[1 : 3 * OSCILLATORS : 3] *= -0.5
        y[-1] = 0.0
        return y

    switch = (lambda _rng: lambda y: y[-1] - 0.5, 1, "damped", reset)
    times = np.linspace(0, 1.0, 21)
    states, where, finals = simulate(x0, 1.0, {"free": (moving(0.0), [switch]), "damped": (moving(0.3), [])}, "free", times, rng)
    assert (where[:, -1] == "damped").all()
    widths = check(run, times, states, where, finals, spec.variables)
    spread = finals.max(0) - finals.min(0)
    # Useful, not only sound: the oscillators with symbols within 2.3 times the sampled spread,
    # those whose x had none left (an interval, wrapped at every step) within 5.1.
    bad = widths[:-1] > 6 * spread[:-1] + 0.02
    assert not bad.any(), [(spec.variables[i], widths[i], spread[i]) for i in np.flatnonzero(bad)]


class TestBadInput:
    def test_undeclared_variables_name_file_and_line(self, tmp_path):
        text = (EXAMPLES / "bouncing_ball.model").read_text()
        path = tmp_path / "bad.model"
        path.write_text(text.replace("guard { x <= 0 y <= 0 }", "guard { x <= 0 z <= 0 }"))
        line = text.split("\n").index("  guard { x <= 0 y <= 0 }") + 1
        with pytest.raises(pv.ParseError, match=rf"bad.model, line {line}, column \d+: .*'z' not declared in 'state var'"):
            pv.formats.load_flowstar(str(path))

    def test_modes_coupling_more_variables_than_taylor_models_hold_name_the_limit(self, tmp_path):
        # v0' = v1, v1' = v2, ...: 33 variables that move together (still ones would not count).
        names = [f"v{i}" for i in range(33)]
        odes = "\n".join(f"    {v}' = {names[(i + 1) % 33]}" for i, v in enumerate(names))
        text = (EXAMPLES / "bouncing_ball.model").read_text().replace("state var x, y", f"state var x, y, {', '.join(names)}")
        path = tmp_path / "wide.model"
        path.write_text(text.replace("    y' = -9.81", f"    y' = -9.81\n{odes}"))
        with pytest.raises(pv.InputError, match="mode 'fly': 33 variables .* move together"):
            pv.formats.load_flowstar(str(path)).run()

    def test_hybrid_flowpipe_needs_an_automaton_without_inputs(self):
        x, u = pv.variables("x u")
        plant = pv.Hybrid({"a": pv.Mode({x: u})}, [], inputs=[u], max_time=1, step=0.1)
        with pytest.raises(pv.InputError, match="reads inputs"):
            pv.hybrid_flowpipe(plant, {x: (0, 1)}, 1.0)


def test_a_failed_run_says_where_why_and_what_to_try(tmp_path):
    # x' = x^2 from x in [1, 1.1] escapes before t = 1: no flowpipe gets to the horizon 2.
    text = (EXAMPLES / "bouncing_ball.model").read_text()
    text = text.replace("x' = y", "x' = x * x").replace("y' = -9.81", "y' = 0").replace("time 1.5", "time 2")
    path = tmp_path / "escape.model"
    path.write_text(text)
    model = pv.formats.load_flowstar(str(path))
    failure = model.run().failure
    assert failure and "in mode 'fly'" in failure and "could not be enclosed" in failure and "jumps='box'" in failure, failure
    boxed = model.run(jumps="box").failure
    assert boxed and "jumps='box'" not in boxed, boxed
