"""A self-test campaign: generate programs, verify each with percver, check the result against the
oracle, and on a violation shrink the program and write a reproducer."""

from __future__ import annotations

import shutil
import time
import traceback
import warnings
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import numpy as np

from percver.selftest.generator import generate
from percver.selftest.oracle import Report, Simulator, Violation, check
from percver.selftest.program import Cond, Const, Program, Var, loop_source


@dataclass
class Outcome:
    """One program's verification: its verdict (or the PercverError class it raised) and the oracle's report."""

    verdict: str
    report: Report
    result: object = None


def build(program: Program) -> dict:
    """Runs the program's source: the namespace holds ``loop``, ``kwargs`` and (with networks) ``DIR``."""
    namespace: dict = {}
    exec(compile(loop_source(program), "<selftest program>", "exec"), namespace)
    return namespace


def run(program: Program, runs: int, seed: int) -> Outcome:
    """Verifies ``program`` (:func:`verify_with_percver`) and checks the result with ``runs``
    oracle runs. An exception from percver that is not a ``PercverError`` is a violation
    ("crash"): every error a user can cause must be one.

    A cell falsified by percver's probes (its centre and corners) before the engine ran has no
    reach boxes; then the loop is verified once more against a property that always holds
    (:func:`boxes_only`), so that its boxes are checked too."""
    outcome = _run(program, runs, seed)
    if outcome.result is not None and not outcome.report.violations and any(not c.boxes for c in outcome.result.cells):
        again = _run(boxes_only(program), runs, seed)
        outcome.report.runs += again.report.runs
        outcome.report.box_checks += again.report.box_checks
        outcome.report.diverged += again.report.diverged
        outcome.report.violations += again.report.violations
    return outcome


def boxes_only(program: Program) -> Program:
    """The program with a property every run meets (its first state stays below 1e300)."""
    return replace(program, safe=[Cond(Var(program.states[0]), "<=", Const(1e300))], unsafe=[], goal=[], within=False)


def verify_with_percver(loop, kwargs: dict):
    """The verification under test: ``pv.verify`` on one worker (tests put a faulty one here)."""
    import percver as pv

    return pv.verify(loop, **kwargs, workers=1, progress=False)


def _run(program: Program, runs: int, seed: int) -> Outcome:
    import percver as pv

    namespace: dict = {}
    try:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                namespace = build(program)
                result = verify_with_percver(namespace["loop"], namespace["kwargs"])
        except pv.PercverError as error:
            return Outcome(type(error).__name__, Report())
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as error:  # a Rust panic arrives as pyo3's PanicException, a BaseException
            text = "".join(traceback.format_exception_only(type(error), error)).strip()
            return Outcome("crash", Report(violations=[Violation("crash", text, program=program)]))
        files = [namespace["DIR"] / f"net{k + 1}.onnx" for k in range(len(program.nets()))] if "DIR" in namespace else None
        ids = [namespace[f"p{i + 1}"].parameters()[0][0] for i in range(len(program.params))]
        report = check(program, Simulator(program, files), result, runs, np.random.default_rng([seed, 7]), ids)
        for v in report.violations:
            v.program = program
        return Outcome(result.verdict, report, result)
    finally:
        if "DIR" in namespace:
            shutil.rmtree(namespace["DIR"], ignore_errors=True)


@dataclass
class Finding:
    """A violation: the program that showed it, its shrunk form and a runnable reproducer."""

    index: int
    violation: Violation
    program: Program
    shrunk: Program
    shrunk_violation: Violation
    reproducer: str


@dataclass
class Tally:
    seed: int
    programs: int = 0
    runs: int = 0
    box_checks: int = 0
    diverged: int = 0
    seconds: float = 0.0
    verdicts: Counter = field(default_factory=Counter)
    findings: list = field(default_factory=list)

    def line(self) -> str:
        verdicts = ", ".join(f"{k} {v}" for k, v in sorted(self.verdicts.items()))
        found = len(self.findings)
        return (
            f"seed {self.seed}: {self.programs} program{'s' * (self.programs != 1)} ({verdicts}), {self.runs:,} runs sampled, "
            f"{self.box_checks:,} box checks, {found} violation{'s' * (found != 1)} in {self.seconds:.0f} s"
            + (f" ({self.diverged:,} runs not finite in the oracle, left out)" if self.diverged else "")
        )


def run_campaign(
    seed: int = 0,
    *,
    programs: Optional[int] = None,
    minutes: Optional[float] = None,
    runs: int = 350,
    start: int = 0,
    shrink_seconds: float = 120.0,
    keep_going: bool = False,
    progress: bool = False,
    on_finding: Optional[Callable] = None,
) -> Tally:
    """Programs ``start``, ``start + 1``, ... of ``seed`` until ``programs`` are done or ``minutes`` have passed (the
    first that comes), each checked with ``runs`` oracle runs. Stops at the first violation unless
    ``keep_going``; each violation is shrunk for up to ``shrink_seconds`` (0: not at all) and
    passed to ``on_finding``."""
    if programs is None and minutes is None:
        raise ValueError("give programs= or minutes= (or both)")
    from tqdm import tqdm

    tally = Tally(seed)
    started = time.monotonic()
    deadline = started + 60 * minutes if minutes is not None else None
    bar = tqdm(total=programs, unit="program", desc="selftest", disable=not progress)
    try:
        index = start
        while (programs is None or index < start + programs) and (deadline is None or time.monotonic() < deadline):
            program = generate(seed, index)
            outcome = run(program, runs, seed)
            tally.programs += 1
            tally.runs += outcome.report.runs
            tally.box_checks += outcome.report.box_checks
            tally.diverged += outcome.report.diverged
            tally.verdicts[outcome.verdict] += 1
            bar.update(1)
            bar.set_postfix(
                runs=tally.runs, boxes=tally.box_checks, violations=len(tally.findings) + len(outcome.report.violations), refresh=False
            )
            if outcome.report.violations:
                finding = _finding(index, program, outcome.report.violations[0], runs, seed, shrink_seconds)
                tally.findings.append(finding)
                if on_finding:
                    on_finding(finding)
                if not keep_going:
                    break
            index += 1
    finally:
        bar.close()
        tally.seconds = time.monotonic() - started
    return tally


def _finding(index: int, program: Program, violation: Violation, runs: int, seed: int, seconds: float) -> Finding:
    from percver.selftest.shrink import shrink as shrunk_form

    small, small_violation = violation.program, violation  # the boxes-only form when its rerun failed
    if seconds > 0:

        def fails(candidate: Program) -> Optional[Violation]:
            found = run(candidate, runs, seed).report.violations
            return next((v for v in found if v.kind == violation.kind), None)

        small, small_violation = shrunk_form(small, violation, fails, seconds)
    return Finding(index, violation, program, small, small_violation, reproducer(small, small_violation, seed, index))


def reproducer(program: Program, violation: Violation, seed: int, index: int) -> str:
    """A script that builds the loop, verifies it and prints what the oracle found wrong."""
    w = violation.witness
    lines = [
        f'"""percver selftest (seed {seed}, program {index}): {violation.kind}.',
        "",
        *_wrap(violation.message),
        '"""',
        "",
        loop_source(program).rstrip(),
        "res = pv.verify(loop, **kwargs, progress=False)",
        "print('verdict:', res.verdict)",
    ]
    if violation.kind == "box":
        j = program.all_states.index(w["state"])
        lines += [
            f"# The run from {_assignments(program, w['initial'], w['params'])} has {w['state']} = {w['value']!r} at step {w['step']}",
            f"# (its trajectory: {w['trajectory']}).",
            f"print('reach box of {w['state']} at step {w['step']} in cell {w['cell']}:', res.cells[{w['cell']}].boxes[{w['step']}][{j}])",
        ]
    elif violation.kind == "verified-but-violated":
        lines += [
            f"# The run from {_assignments(program, w['initial'], w['params'])} violates {w['label']} at step {w['step']}",
            f"# (its trajectory: {w['trajectory']}).",
        ]
    elif violation.kind == "counterexample":
        lines += [
            f"# percver's counterexample for cell {w['cell']} starts at {_assignments(program, w['initial'], w['params'])}",
            f"# (claimed: {w['label']} at step {w['step']}); the oracle's run from there does not violate the property.",
            f"print(res.cells[{w['cell']}].counterexample)",
        ]
    return "\n".join(lines) + "\n"


def _assignments(program: Program, initial: list, params: list) -> str:
    text = ", ".join(f"{s}={v!r}" for s, v in zip(program.all_states, initial))
    return text + ("" if not params else " with " + ", ".join(f"p{i + 1}={v!r}" for i, v in enumerate(params)))


def _wrap(text: str, width: int = 100) -> list:
    import textwrap

    return textwrap.wrap(text, width) or [""]
