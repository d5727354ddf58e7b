"""``percver selftest``: the campaign CI runs (random loops checked against the independent float
oracle), and tests that the oracle, the generator and the shrinker do their part: the oracle agrees
with percver's own simulation where both are right and catches planted wrong results, the
generator makes the fork-alias class of issue 24, the shrinker keeps a failure while it shrinks."""

import shutil
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest

import percver as pv
import percver.selftest.campaign as campaign_module
from percver.selftest.campaign import boxes_only, build, reproducer, run, run_campaign
from percver.selftest.campaign import verify_with_percver as sound_verify
from percver.selftest.generator import aliasing_pairs, generate
from percver.selftest.oracle import ODE_TOLERANCE, Simulator, check, holds, sample
from percver.selftest.program import SIMPLEST, Binary, Cond, Const, Net, Param, Program, Stage, Unary, Var, Where, walk
from percver.selftest.shrink import shrink
from percver.verification.results import Cell, Result

CI_SEED, CI_PROGRAMS, CI_RUNS = 2024, 320, 330


def test_ci_campaign_finds_no_violation():
    """320 random loops, over 10^5 sampled runs: no verified cell with a violating run, no run
    outside a reach box, every counterexample replays, no crash."""
    tally = run_campaign(CI_SEED, programs=CI_PROGRAMS, runs=CI_RUNS, keep_going=True)
    print(tally.line())  # the counts, in the log of a run with -s
    assert not tally.findings, "\n\n".join(f.reproducer for f in tally.findings)
    assert tally.programs == CI_PROGRAMS and tally.runs >= 100_000, tally.line()
    # The campaign reached every outcome, with boxes to check in most programs.
    assert min(tally.verdicts[v] for v in ("verified", "unknown", "falsified")) >= 30, tally.line()
    assert tally.box_checks >= 3 * tally.runs, tally.line()


def _ids(namespace, program):
    return [namespace[f"p{i + 1}"].parameters()[0][0] for i in range(len(program.params))]


@pytest.mark.parametrize("index", range(40))
def test_oracle_steps_are_percver_steps(index):
    """The oracle (numpy, onnxruntime, scipy) and percver's simulator, two implementations of one
    program, take the same steps from the same states (same parameter values): the source
    rendering means what the oracle computes, so a violation is the engine's, not a misreading of
    the program. Step by step, since a fast wave of a network output (cos(1000 u)) turns the
    last-digit differences of two evaluation orders into different runs within a few steps."""
    program = generate(CI_SEED + 1, index)
    x0, params = sample(program, program.start, 64, np.random.default_rng(index))
    with _built(program) as (namespace, simulator), np.errstate(all="ignore"):
        loop, kwargs = namespace["loop"], namespace["kwargs"]
        loop = loop.with_accumulators(kwargs["reward"]) if "reward" in kwargs else loop
        theirs = loop.simulate(x0, program.steps, parameters=dict(zip(_ids(namespace, program), params.T)))
        ours = np.stack([simulator.step(theirs[:, t], params) for t in range(program.steps)], axis=1)
    theirs = theirs[:, 1:]
    finite = np.isfinite(ours).all(axis=2) & np.isfinite(theirs).all(axis=2)
    assert finite.mean() >= 0.5
    # A where at its threshold may go either way between two evaluation orders; integrators differ in the last digits.
    close = np.isclose(ours[finite], theirs[finite], rtol=1e-7 if program.continuous else 1e-9, atol=1e-10).all(axis=1)
    assert close.mean() >= 0.98, f"{np.count_nonzero(~close)} of {len(close)} steps differ"


def _network_loop(continuous: bool) -> Program:
    """x' = -x + u (or x <- x + 0.1 u) with u from a small tanh network of (x, y), y a constant."""
    net = Net([([[0.8, -0.5], [0.3, 0.9]], [0.1, -0.2], "tanh"), ([[1.2, -0.7]], [0.05], "identity")], scale=[0.5], style="matmul")
    stages = [Stage("u", ["x", "y"], nets=[net])]
    x, y, u = Var("x"), Var("y"), Var("u")
    if continuous:
        update = {"x": Binary("-", u, x), "y": Const(0.0)}
        return Program(
            ["x", "y"],
            {"x": (0.4, 0.6), "y": (-0.1, 0.1)},
            update,
            stages,
            period=0.13,
            step=0.13 / 3,
            inputs=["u"],
            safe=[Cond(x, "<=", Const(2.0))],
            steps=3,
            options=SIMPLEST,
        )
    update = {"x": Binary("+", x, Binary("*", Const(0.1), u)), "y": y}
    return Program(
        ["x", "y"], {"x": (0.4, 0.6), "y": (-0.1, 0.1)}, update, stages, safe=[Cond(x, "<=", Const(2.0))], steps=4, options=SIMPLEST
    )


@contextmanager
def _built(program: Program):
    """The program's namespace (loop, kwargs) and its oracle simulator on the network files it wrote."""
    namespace = build(program)
    try:
        files = [namespace["DIR"] / f"net{k + 1}.onnx" for k in range(len(program.nets()))] if "DIR" in namespace else None
        yield namespace, Simulator(program, files)
    finally:
        if "DIR" in namespace:
            shutil.rmtree(namespace["DIR"])


def _checked(program: Program, result=None, runs: int = 300):
    """(result, report) of the oracle on ``result`` (default: percver's own)."""
    with _built(program) as (namespace, simulator):
        result = result or pv.verify(namespace["loop"], **namespace["kwargs"], progress=False)
        return result, check(program, simulator, result, runs, np.random.default_rng(1), _ids(namespace, program))


def _sampled_max(program: Program, result, step: int, runs: int = 300) -> float:
    """The largest x at ``step`` among the runs :func:`check` samples (the same draws)."""
    x0, params = sample(program, result.cells[0].box, runs, np.random.default_rng(1))
    with _built(program) as (_, simulator):
        return float(simulator.simulate(x0, params)[:, step, 0].max())


@pytest.mark.parametrize("continuous", [False, True])
def test_the_oracle_catches_a_box_that_misses_a_run(continuous):
    """A correct result passes; the same result with a box lowered to just below the highest
    sampled run is caught: 1 ulp below for a discrete plant (no tolerance), 2x the integrator's
    allowance for a continuous one (and half of it passes)."""
    program = _network_loop(continuous)
    result, report = _checked(program)
    assert result.verdict == "verified" and not report.violations and report.box_checks > 0
    top = _sampled_max(program, result, 2)
    lo = result.cells[0].boxes[2][0][0]
    below = (
        [(np.nextafter(top, -np.inf), True)]
        if not continuous
        else [(top - 2 * ODE_TOLERANCE * (1 + abs(top)), True), (top - 0.5 * ODE_TOLERANCE * (1 + abs(top)), False)]
    )
    for hi, caught in below:
        result.cells[0].boxes[2][0] = (lo, hi)
        _, report = _checked(program, result)
        assert [v.kind for v in report.violations] == (["box"] if caught else []), (hi, top)
        if caught:
            w = report.violations[0].witness
            assert (w["step"], w["state"], w["value"]) == (2, "x", top)


def test_the_oracle_catches_a_verified_verdict_on_an_unsafe_loop():
    program = replace(_network_loop(False), safe=[Cond(Var("x"), "<=", Const(0.55))])
    result, report = _checked(program)
    assert result.verdict == "falsified" and not report.violations
    planted = Result(result.states, result.init, [Cell(c.box, "verified", boxes=c.boxes) for c in result.cells])
    _, report = _checked(program, planted)
    assert {v.kind for v in report.violations} == {"verified-but-violated"}


def test_the_oracle_catches_a_counterexample_that_does_not_replay():
    program = replace(_network_loop(False), safe=[Cond(Var("x"), "<=", Const(0.55))])
    result, report = _checked(program)
    cell = next(c for c in result.cells if c.counterexample)
    assert not report.violations
    cell.counterexample.initial = {**cell.counterexample.initial, "x": 0.4}  # a start from which every run is safe
    _, report = _checked(program, result)
    assert [v.kind for v in report.violations] == ["counterexample"]


def _issue_24() -> Program:
    """The reproducer of issue 24 as a program: c gains where(sin(1000 x) <= 0, 1, 0) + where(sin(1000 y) <= 0, 0, 1)."""
    x, y, c = Var("x"), Var("y"), Var("c")
    wave = lambda v: Cond(Unary("sin", Binary("*", Const(1000.0), v)), "<=", Const(0.0))
    gain = Binary("+", Where(wave(x), Const(1.0), Const(0.0)), Where(wave(y), Const(0.0), Const(1.0)))
    return Program(
        ["x", "y", "c"],
        {"x": (0.0031, 0.0131), "y": (0.0031, 0.0131), "c": (0.0, 0.0)},
        {"x": x, "y": y, "c": Binary("+", c, gain)},
        safe=[Cond(c, "<=", Const(1.5))],
        options=SIMPLEST,
    )


def test_the_oracle_catches_the_merged_branches_of_issue_24():
    """What the engine answered before the fix (verified; c in [1, 1] after the step) is caught
    twice over: runs reach c = 0 and c = 2 outside the box, and c = 2 breaks c <= 1.5."""
    program = _issue_24()
    assert aliasing_pairs(program)
    box = {"x": (0.0031, 0.0131), "y": (0.0031, 0.0131), "c": (0.0, 0.0)}
    boxes = [[(0.0031, 0.0131), (0.0031, 0.0131), (0.0, 0.0)], [(0.0031, 0.0131), (0.0031, 0.0131), (1.0, 1.0)]]
    merged = Result(["x", "y", "c"], box, [Cell(box, "verified", boxes=boxes)], settings={"steps": 1})
    _, report = _checked(program, merged)
    assert {v.kind for v in report.violations} == {"box", "verified-but-violated"}
    # And the engine of today does not verify it; the oracle agrees with what it reports.
    outcome = run(program, 300, 0)
    assert outcome.verdict != "verified" and not outcome.report.violations


def test_the_generator_makes_the_fork_alias_class():
    """Among the CI campaign's programs, several ask two conditions about different quantities
    whose models are equal on the initial set (issue 24's class), and the oracle's runs take every
    combination of their branches, so an engine that ties the two is caught."""
    programs = [generate(CI_SEED, i) for i in range(CI_PROGRAMS)]
    alias = [p for p in programs if aliasing_pairs(p)]
    assert len(alias) >= 5
    kinds = set()
    for p in alias:
        a, b = aliasing_pairs(p)[0]
        kinds.add(type(a.lhs).__name__)
        x0, params = sample(p, p.start, 400, np.random.default_rng(0))
        with np.errstate(all="ignore"):
            env = Simulator(p).environment(x0, params)
        combos = set(zip(holds(a, env, params), holds(b, env, params)))
        assert combos == {(True, True), (True, False), (False, True), (False, False)}, (a, b)
    assert kinds == {"Param", "Unary"}  # parameters with equal ranges, and waves of different states


def _nodes(program: Program) -> int:
    return sum(1 for e in program.expressions() + program.conditions() for _ in walk(e)) + 10 * len(program.stages)


def test_shrinking_keeps_the_failure_and_simplifies():
    """With a stand-in failure (the plant's update has a condition on a parameter), shrinking
    ends at a smaller program that still has it: one step, the plainest options, no stages."""

    def has_param_condition(p):
        return any(isinstance(n, Where) and isinstance(n.cond.lhs, Param) for e in p.update.values() for n in walk(e))

    program = next(
        p for p in (generate(CI_SEED, i) for i in range(200)) if has_param_condition(p) and p.stages and p.steps > 1 and p.options
    )
    small, found = shrink(program, "planted", lambda p: "planted" if has_param_condition(p) else None, seconds=60)
    assert found == "planted" and has_param_condition(small)
    assert small.steps == 1 and small.options == SIMPLEST and not small.stages and _nodes(small) < _nodes(program)


def _unsound(loop, kwargs):
    """percver's verify with each reach box cut to its lower half from step 1 on."""
    result = sound_verify(loop, kwargs)
    for cell in result.cells:
        cell.boxes = cell.boxes[:1] + [[(lo, lo + 0.5 * (hi - lo)) for lo, hi in box] for box in cell.boxes[1:]]
    return result


def test_a_faulty_engine_is_caught_shrunk_and_reproduced(monkeypatch, capsys):
    """Put an engine whose boxes are too small in place: the CLI campaign reports a box violation,
    shrinks it, prints a reproducer that runs, and exits 1."""
    from percver.cli import main

    monkeypatch.setattr(campaign_module, "verify_with_percver", _unsound)
    assert main(["selftest", "--programs", "20", "--seed", "3", "--shrink-seconds", "20", "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert "VIOLATION in program" in out and "(box)" in out and "1 violation in" in out
    script = out.split("-" * 72 + "\n")[1]
    namespace: dict = {}
    exec(compile(script, "<reproducer>", "exec"), namespace)  # runnable (with the sound engine: it prints the box)
    assert "res" in namespace and namespace["res"].cells


def test_cli_clean_run_and_bad_usage(capsys):
    from percver.cli import main

    assert main(["selftest", "--programs", "4", "--seed", "5", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "seed 5: 4 programs" in out and "runs sampled" in out and "box checks" in out and "0 violations" in out
    assert main(["selftest", "--programs", "0"]) == 2


def test_boxes_only_rerun_checks_boxes_of_probe_falsified_loops():
    """A loop falsified by percver's probes before the engine runs has no boxes; the campaign
    verifies it again against a property every run meets and checks those boxes."""
    program = replace(_network_loop(False), safe=[Cond(Var("x"), "<=", Const(0.41))])
    result, report = _checked(program)
    assert result.verdict == "falsified" and not any(c.boxes for c in result.cells) and report.box_checks == 0
    outcome = run(program, 200, 0)
    assert outcome.verdict == "falsified" and outcome.report.box_checks > 0 and not outcome.report.violations
    assert boxes_only(program).conditions() == [Cond(Var("x"), "<=", Const(1e300))]


def test_the_reproducer_of_a_violation_names_the_witness():
    program = _issue_24()
    box = dict(program.init)
    merged = Result(
        ["x", "y", "c"],
        box,
        [Cell(box, "verified", boxes=[list(box.values()), [(0.0031, 0.0131)] * 2 + [(1.0, 1.0)]])],
        settings={"steps": 1},
    )
    _, report = _checked(program, merged)
    violation = next(v for v in report.violations if v.kind == "box")
    text = reproducer(program, violation, 0, 0)
    assert "res.cells[0].boxes[1][2]" in text and "has c = " in text and "pv.where" in text
