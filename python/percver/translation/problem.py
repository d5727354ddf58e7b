"""A translated Verisig benchmark: the closed loop with the file's initial set and property."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from percver.expr import Condition, Expr
from percver.systems import ClosedLoop, Continuous, Discrete, Hybrid


@dataclass
class VerisigProblem:
    """A Verisig benchmark as a percver closed loop with the file's initial set and property.

    ``pv.verify(problem, ...)`` and ``problem.verify(...)`` use ``defaults`` (init, steps, goal,
    safe, within) for whatever is not given. ``notes`` records every liberty the translation
    took (ignored settings, dropped jumps, added obligations), ``summary()`` prints the result.
    """

    path: str
    loop: ClosedLoop
    init: dict
    steps: int
    goal: Optional[Condition] = None
    safe: list = field(default_factory=list)
    within: bool = False
    period: Optional[float] = None  # control period of a continuous plant
    networks: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return "continuous" if isinstance(self.loop.plant, Continuous) else "hybrid" if isinstance(self.loop.plant, Hybrid) else "discrete"

    @property
    def states(self) -> list:
        return self.loop.states

    @property
    def defaults(self) -> dict:
        return {"init": dict(self.init), "steps": self.steps, "goal": self.goal, "safe": list(self.safe) or None, "within": self.within}

    def verify(self, **kwargs):
        """``pv.verify`` with this file's initial set, horizon and property as defaults."""
        from percver.verification import verify

        return verify(self, **kwargs)

    def simulate(self, x0, steps: Optional[int] = None) -> np.ndarray:
        return self.loop.simulate(x0, self.steps if steps is None else steps)

    def summary(self) -> str:
        """What the file became: plant, stages, property (long expressions shortened)."""

        def short(e, n=110):
            s = str(e)
            return s if len(s) <= n else s[: n - 3] + "..."

        def opaque(e):
            # Composed updates share subexpressions; printing expands them (exponentially).
            return f"<composed expression over {', '.join(e.variables())}>" if isinstance(e, Expr) else repr(e)

        plant = self.loop.plant
        lines = [f"{Path(self.path).name}: {self.kind} plant, states {', '.join(self.states)}"]
        if isinstance(plant, Discrete):
            lines += [f"  {s}+ = {opaque(e)}" for s, e in zip(plant.states, plant.update)]
        elif isinstance(plant, Hybrid):
            for name in plant.modes:
                lines.append(f"  mode {name}: " + "; ".join(f"{s}' = {short(e, 60)}" for s, e in zip(plant.states, plant.rhs_of(name))))
            lines += [
                f"  jump {j.source} -> {j.target or 'the networks'} when {' and '.join(map(str, j.guard)) or 'always'}" for j in plant.jumps
            ]
            lines.append(f"  inputs {', '.join(plant.inputs)} held for {self.period} s")
        else:
            lines += [f"  {s}' = {short(e)}" for s, e in zip(plant.states, plant.rhs)]
            lines.append(f"  inputs {', '.join(plant.inputs)} held for {self.period} s")
        for st in self.loop.stages:
            if st.is_network:
                net = st.component
                lines.append(
                    f"  stage {st.output} = network {net.name or ''} ({net.n_in} -> {net.n_out}) of {', '.join(st.input_labels)}"
                    + (
                        f", scale {np.asarray(net.scale).tolist()} offset {np.asarray(net.offset).tolist()}"
                        if net.scale is not None
                        else ""
                    )
                )
            elif st.input_names:
                lines.append(f"  stage {st.output} = {len(st.component)} expression(s) of {', '.join(st.input_names)}")
            else:
                lines.append(f"  stage {st.output} = constants {', '.join(map(str, st.component))}")
        lines.append(f"  init {self.init}, {self.steps} steps")
        for c in self.safe:
            lines.append(f"  safe at every step: {short(c)}")
        if self.goal is not None:
            lines.append(f"  goal {'within' if self.within else 'at'} step {self.steps}: {short(self.goal)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def __repr__(self):
        return f"<VerisigProblem {Path(self.path).name}: {self.kind}, {len(self.states)} states, {self.steps} steps>"


def make_problem(ex, loop, init, H, goal, safe, within, period) -> VerisigProblem:
    ignored = ex.aut.settings.unused("time", "max_jumps")
    if ignored:
        ex.notes.append(f"Flow* integration settings not used by percver: {'; '.join(ignored)}")
    return VerisigProblem(
        ex.src.path,
        loop,
        init,
        H,
        goal,
        safe,
        within,
        period,
        list(ex.networks),
        ex.notes,
        {k: getattr(ex.aut.settings, k) for k in ("time", "max_jumps") if getattr(ex.aut.settings, k) is not None},
    )
