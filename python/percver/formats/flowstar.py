"""Flow* model files: parse them and run them with their own settings.

``continuous reachability``: ``state var``, the settings block (fixed/adaptive steps and orders,
time, remainder estimation as a number or per variable, QR/identity precondition, cutoff;
plotting, output, precision and print lines are read and ignored), ``poly ode N`` / ``nonpoly
ode`` / ``nonpoly ode { N }`` (all integrated by the same Taylor-model Picard engine), and
``init``. Anything else is refused with the file name, line, column and what is supported.

``hybrid reachability``: modes with ODEs and invariants, jumps with guards and resets, the initial mode and box, the
horizon ``time`` and ``max jumps``. The reader gives a :class:`FlowstarHybrid`: the automaton as a
:class:`percver.Hybrid`, whose reach set :func:`percver.flowpipe.hybrid_flowpipe` computes with
Taylor models carried through the jumps (Flow*'s way; ``run(jumps="box")`` boxes them instead).

Both are read by :mod:`percver.formats.flowstar_syntax`, the parser the Verisig reader shares.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Union

from percver.flowpipe import HybridFlowpipe, hybrid_flowpipe
from percver.formats.flowstar_syntax import Automaton, Settings, Source, ast_variables, parse, position_of, to_expr
from percver.systems import Hybrid, Jump, Mode


@dataclass
class FlowstarModel:
    path: str
    variables: list
    odes: dict  # name -> expression text
    init: dict  # name -> (lo, hi)
    t_end: float
    step: object  # float or (min, max)
    order: object  # int or (min, max)
    remainder: list
    precondition: str = "identity"
    cutoff: float = 1e-10
    ode_kind: str = "nonpoly ode"
    symbolic_queue: int = 100
    ignored: list = field(default_factory=list)
    rhs: dict = field(default_factory=dict, repr=False, compare=False)  # name -> Expr of odes[name]

    def run(self, *, progress: bool = False, on_failure: str = "raise", refinements: int = 30):
        """Integrate with the file's settings; returns a :class:`percver.flowpipe.Flowpipe`."""
        from percver.flowpipe import flowpipe

        ode = {v: self.rhs[v] for v in self.variables}
        adaptive = self.step if isinstance(self.step, tuple) else None
        step = self.step if not isinstance(self.step, tuple) else 0.0
        return flowpipe(
            ode,
            {v: self.init[v] for v in self.variables},
            self.t_end,
            order=self.order,
            step=step,
            adaptive=adaptive,
            precondition=self.precondition,
            cutoff=self.cutoff,
            remainder=dict(zip(self.variables, self.remainder)),
            refinements=refinements,
            symbolic_queue=self.symbolic_queue,
            progress=progress,
            on_failure=on_failure,
        )


def _integration(src, settings: Settings) -> None:
    """Refuses settings percver does not know and checks the step, order and horizon are given."""
    for key, line, pos in settings.lines:
        if key is None:
            raise src.error(
                pos,
                f"unsupported setting '{line}' (percver reads steps, orders, time, remainder estimation, precondition, cutoff, max jumps)",
            )
    required = (
        ("step: add 'fixed steps h' or 'adaptive steps { min a, max b }'", settings.step),
        ("order: add 'fixed orders k' or 'adaptive orders { min k, max m }'", settings.order),
        ("time horizon: add 'time T'", settings.time),
    )
    for what, value in required:
        if value is None:
            raise src.error(settings.pos, f"the setting block gives no {what}")


def load_flowstar(path: str) -> Union[FlowstarModel, FlowstarHybrid]:
    """Parses a Flow* model file: a :class:`FlowstarModel` (continuous) or a :class:`FlowstarHybrid`."""
    model = parse(Source.read(path, "Flow* model"))
    if isinstance(model, Automaton):
        return _hybrid(model)
    src, variables, found = model.src, model.variables, model.settings
    _integration(src, found)
    for v, (ast, rhs) in model.odes.items():
        unknown = sorted(ast_variables(ast) - set(variables))
        if unknown:
            raise src.error(
                position_of(ast, unknown[0]),
                f'the ODE "{v}\' = {rhs}" uses {", ".join(map(repr, unknown))}, which is not a state variable '
                f"(state var: {', '.join(variables)}); declare it or fix the name",
            )
    missing = [v for v in variables if v not in model.odes]
    if missing:
        raise src.error(model.ode_pos, f'no equation for {", ".join(missing)}; add "{missing[0]}\' = ..." to the ODE block')
    missing = [v for v in variables if v not in model.init]
    if missing:
        raise src.error(model.init_pos, f"the init block gives no interval for {', '.join(missing)}")
    return FlowstarModel(
        src.path,
        variables,
        {v: rhs for v, (_, rhs) in model.odes.items()},
        model.init,
        found.time,
        found.step,
        found.order,
        found.remainders(variables),
        found.precondition,
        found.cutoff,
        model.ode_kind,
        # percver always keeps remainders symbolically; the file may size the queue
        100 if model.symbolic_queue is None else max(1, model.symbolic_queue),
        found.unused("step", "order", "time", "remainder", "precondition", "cutoff"),
        {v: to_expr(model.odes[v][0]) for v in variables},
    )


# ----------------------------------------------------------------------------- hybrid models


@dataclass
class FlowstarHybrid:
    """A Flow* ``hybrid reachability`` model as read: the automaton (``plant``, a
    :class:`percver.Hybrid` starting in the file's initial mode), the initial box and the file's
    settings. :meth:`run` hands them to :func:`percver.flowpipe.hybrid_flowpipe`."""

    path: str
    plant: Hybrid
    init: dict
    t_end: float
    max_jumps: int
    step: object  # float or (min, max)
    order: object  # int or (min, max)
    remainder: list
    cutoff: float
    ignored: list = field(default_factory=list)

    @property
    def variables(self) -> list:
        return self.plant.states

    @property
    def modes(self) -> dict:
        return self.plant.modes

    @property
    def jumps(self) -> list:
        return self.plant.jumps

    def run(self, *, jumps: str = "taylor", max_branches: int = 64) -> HybridFlowpipe:
        """The reach set with the file's settings (see :func:`percver.flowpipe.hybrid_flowpipe`)."""
        return hybrid_flowpipe(
            self.plant,
            self.init,
            self.t_end,
            order=self.order,
            step=self.step,
            cutoff=self.cutoff,
            remainder=self.remainder,
            max_jumps=self.max_jumps,
            max_branches=max_branches,
            jumps=jumps,
        )


def _conditions(src, atoms: list, variables: set, where: str) -> list:
    """Conditions of ``lhs op rhs`` atoms (``=`` as both ``<=`` and ``>=``)."""
    out = []
    for lhs, op, rhs, _ in atoms:
        unknown = sorted((ast_variables(lhs) | ast_variables(rhs)) - variables)
        if unknown:
            raise src.error(
                position_of(("bin", "-", lhs, rhs), unknown[0]), f"{where}: {', '.join(map(repr, unknown))} not declared in 'state var'"
            )
        margin = to_expr(("bin", "-", lhs, rhs))
        out += [margin <= 0] if op in ("<=", "<", "=") else []
        out += [margin >= 0] if op in (">=", ">", "=") else []
    return out


def _hybrid(aut: Automaton) -> FlowstarHybrid:
    src, variables, found = aut.src, aut.variables, aut.settings
    dnn = [name for name in aut.modes if name.startswith("DNN")]
    if dnn:
        raise src.error(
            aut.modes[dnn[0]].pos,
            f"mode {dnn[0]} is a Verisig 2.0 network mode (evaluated by the tool from a network file): read the model with pv.load_verisig(model, networks=[...])",
        )
    _integration(src, found)
    known = set(variables)
    modes = {}
    for name, mode in aut.modes.items():
        rhs = {v: to_expr(mode.ode[v]) if v in mode.ode else 0.0 for v in variables}
        modes[name] = Mode(rhs, invariant=_conditions(src, mode.inv, known, f"invariant of mode {name}"))
    jumps = [
        Jump(
            j.src,
            j.dst,
            guard=_conditions(src, j.guard, known, f"guard of jump {j.src} -> {j.dst}"),
            reset={v: to_expr(ast) for v, ast in j.reset.items()},
        )
        for j in aut.jumps
    ]
    t_end = found.time
    step = found.step
    first = step[1] if isinstance(step, tuple) else step
    plant = Hybrid(
        modes,
        jumps,
        start=aut.init_mode,
        max_time=t_end,
        step=min(first, t_end),
        max_jumps=10**6 if found.max_jumps is None else found.max_jumps,
    )
    ignored = found.unused("step", "order", "time", "remainder", "precondition", "cutoff", "max_jumps")
    ignored += [f"unsafe sets of {sorted(aut.unsafe)} (run() computes reach sets only)"] if aut.unsafe else []
    return FlowstarHybrid(
        src.path,
        plant,
        {v: aut.init.get(v, (0.0, 0.0)) for v in variables},
        t_end,
        plant.max_jumps,
        step,
        found.order,
        found.remainders(variables),
        found.cutoff,
        ignored,
    )
