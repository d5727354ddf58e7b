# Type stubs for percver._core, the pyo3 module built from crates/percver-py/src/*.rs.
# tests/test_packaging.py checks that every name and method the module exports is declared here
# (and nothing else), so a change to the Rust boundary that forgets this file fails CI.
# Errors are raised as percver.errors classes (InputError, DomainError, ParseError, BlowUpError,
# NetworkFormatError), mapped in crates/percver-py/src/error.rs.

from typing import Any, Callable, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import NDArray
from typing_extensions import TypedDict, Unpack

__version__: str

Bounds = Sequence[Tuple[float, float]]
# One DAG node for pickling: (kind, operator/function index, numbers, child indices, name).
FlatNode = Tuple[int, int, Sequence[float], Sequence[int], str]
Operand = Union["Expr", float]

class Interval:
    """A closed interval with outward-rounded arithmetic."""

    def __init__(self, lo: float, hi: Optional[float] = None) -> None: ...
    @property
    def lo(self) -> float: ...
    @property
    def hi(self) -> float: ...
    def is_empty(self) -> bool: ...
    def contains(self, x: float) -> bool: ...
    def __add__(self, o: Interval) -> Interval: ...
    def __sub__(self, o: Interval) -> Interval: ...
    def __mul__(self, o: Interval) -> Interval: ...
    def __truediv__(self, o: Interval) -> Interval: ...
    def __neg__(self) -> Interval: ...
    def div_extended(self, o: Interval) -> Interval:
        """Division that returns the whole line for a divisor containing zero instead of raising."""
    def hull(self, o: Interval) -> Interval: ...
    def intersect(self, o: Interval) -> Interval: ...
    def sqr(self) -> Interval: ...
    def powi(self, n: int) -> Interval: ...
    def powf(self, r: float) -> Interval: ...
    def apply(self, name: str) -> Interval:
        """An elementary function by name: exp log sqrt sin cos tan atan tanh sigmoid abs."""

class Expr:
    """A node of the expression DAG, evaluated on floats, intervals and Taylor models."""

    @staticmethod
    def var(name: str) -> Expr: ...
    @staticmethod
    def constant(value: float) -> Expr: ...
    @staticmethod
    def uncertain(lo: float, hi: float, held: bool = False) -> Expr:
        """A quantity known only to lie in [lo, hi]: new at every evaluation, or with ``held`` a
        constant of the system, the same over a run."""
    @staticmethod
    def parse(text: str) -> Expr: ...
    @staticmethod
    def apply(name: str, arg: Operand) -> Expr: ...
    @staticmethod
    def select(condition: Condition, then: Operand, otherwise: Operand) -> Expr: ...
    @staticmethod
    def minimum(a: Operand, b: Operand) -> Expr: ...
    @staticmethod
    def maximum(a: Operand, b: Operand) -> Expr: ...
    @staticmethod
    def _from_nodes(nodes: Sequence[FlatNode]) -> Expr: ...
    def variables(self) -> list[str]: ...
    def name(self) -> Optional[str]:
        """The variable's name if this expression is a bare variable."""
    def parameters(self) -> list[Tuple[int, float, float]]:
        """The uncertain parameters the expression reads, as (id, lo, hi), each once."""
    def substitute(self, mapping: Mapping[str, Operand], parameters: Optional[Mapping[int, Operand]] = None) -> Expr:
        """The expression with the variables named in `mapping` replaced (shared nodes stay shared,
        parameters keep their identity), and the uncertain parameters whose ids are in `parameters`."""
    def structural_hash(self) -> int:
        """Structural hash (each shared node once): for fingerprints of large expression DAGs."""
    def __add__(self, o: Operand) -> Expr: ...
    def __radd__(self, o: Operand) -> Expr: ...
    def __sub__(self, o: Operand) -> Expr: ...
    def __rsub__(self, o: Operand) -> Expr: ...
    def __mul__(self, o: Operand) -> Expr: ...
    def __rmul__(self, o: Operand) -> Expr: ...
    def __truediv__(self, o: Operand) -> Expr: ...
    def __rtruediv__(self, o: Operand) -> Expr: ...
    def __pow__(self, exponent: float, modulo: None = None) -> Expr: ...
    def __neg__(self) -> Expr: ...
    def __pos__(self) -> Expr: ...
    def __lt__(self, o: Operand) -> Condition: ...
    def __le__(self, o: Operand) -> Condition: ...
    def __gt__(self, o: Operand) -> Condition: ...
    def __ge__(self, o: Operand) -> Condition: ...
    def __hash__(self) -> int: ...

class Condition:
    """A comparison ``lhs op rhs``, the argument of ``where`` and of properties."""

    @property
    def op(self) -> str: ...
    @property
    def lhs(self) -> Expr: ...
    @property
    def rhs(self) -> Expr: ...
    def margin(self) -> Expr:
        """The expression lhs - rhs whose sign the condition tests."""
    def __bool__(self) -> bool: ...

class TaylorModels:
    """Taylor models of expressions over a box (each variable mapped affinely onto [-1, 1])."""

    def bound(self) -> list[Tuple[float, float]]:
        """Naive (monomial-wise) range bound of each model."""
    def range(self) -> list[Tuple[float, float]]:
        """Range bound refined by the linear dominated bounder."""
    def remainders(self) -> list[Tuple[float, float]]: ...
    def degree(self) -> list[int]: ...
    def enclose(self, points: NDArray[np.float64]) -> Tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Rigorous enclosures (lo, hi arrays, N x m) of the models at the given points of the box."""

class FlowpipeResult:
    """A validated flowpipe: one box per time segment."""

    @property
    def names(self) -> list[str]: ...
    @property
    def times(self) -> NDArray[np.float64]:
        """(S, 2) array of segment start and end times."""
    @property
    def boxes(self) -> NDArray[np.float64]:
        """(S, n, 2) array: the box of each segment, lower and upper bounds per variable."""
    @property
    def final_box(self) -> list[Tuple[float, float]]: ...
    @property
    def time_reached(self) -> float: ...
    @property
    def failure(self) -> Optional[str]:
        """Why integration stopped early (None when it reached the horizon)."""
    @property
    def orders(self) -> list[int]: ...
    @property
    def stats(self) -> dict[str, Any]: ...
    def final_models(self) -> list[Tuple[list[Tuple[list[int], float]], Tuple[float, float]]]:
        """The final state's Taylor models over the normalised initial set z in [-1, 1]^n: per
        variable, ([(exponents of z_1..z_n, coefficient)], (remainder lo, hi))."""
    def initial_map(self) -> list[Tuple[float, float]]:
        """(c_i, r_i) of the map x0_i = c_i + r_i z_i from the normalised initial set."""
    def final_bound(self, bounder: str = "dominated", split: int = 4) -> list[Tuple[float, float]]:
        """The final box with a chosen bounder: "dominated", "interval", "subdivision" or "bernstein"."""
    def final_enclose(self, points: Sequence[Sequence[float]]) -> NDArray[np.float64]:
        """Rigorous (N, n, 2) enclosures of the final state reached from each initial point."""

class NetworkModels:
    """Taylor models of a network's outputs (or inputs), ready to be propagated further."""

    def __len__(self) -> int: ...
    def bounds(self) -> list[Tuple[float, float]]:
        """Range of each model (polynomial by the linear dominated bounder, plus symbols and remainder)."""
    def remainders(self) -> list[Tuple[float, float]]:
        """Each model's interval remainder, the error symbols' range included."""
    @property
    def symbols(self) -> int:
        """Error symbols shared between the models (activation errors kept for cancellation)."""
    @property
    def variables(self) -> list[Tuple[int, int, float, float]]:
        """(input index, variable, centre, radius): input = centre + radius * x_variable, x in [-1, 1]."""
    @property
    def order(self) -> int: ...

# The keywords of Network.bounds and Network.models; one left out takes the engine's default
# (nn2hybrid's propagate::Settings::default(): order 5, cutoff 1e-15, symbolic, 4 variables, 4096 symbols).
PropagationOptions = TypedDict(
    "PropagationOptions", {"order": int, "cutoff": float, "symbolic": bool, "max_vars": int, "max_symbols": int}, total=False
)

class Network:
    """A feed-forward network: ``layers`` of (weight n_out x n_in, bias, activations: one name per
    neuron or one per layer), outputs mapped by ``scale`` and ``offset``."""

    def __init__(
        self,
        layers: Sequence[Tuple[NDArray[np.float64], NDArray[np.float64], Sequence[str]]],
        scale: Optional[Sequence[float]] = None,
        offset: Optional[Sequence[float]] = None,
    ) -> None: ...
    @property
    def n_in(self) -> int: ...
    @property
    def n_out(self) -> int: ...
    def bounds(
        self,
        input: Union[Bounds, NetworkModels],
        method: str = "taylor",
        *,
        splits: Sequence[Tuple[int, int]] = ...,
        leaves: int = 1,
        **options: Unpack[PropagationOptions],
    ) -> list[Tuple[float, float]]:
        """Sound output bounds over a box (or over earlier models) by "taylor", "verisig" or "interval";
        ``leaves`` > 1 refines a box's Taylor bounds by branch and bound on the input."""
    def models(self, input: Union[Bounds, NetworkModels], method: str = "taylor", **options: Unpack[PropagationOptions]) -> NetworkModels:
        """The output Taylor models over a box (or over earlier models), to propagate further."""

# A condition for the engine: (margin, op, label) meaning ``margin op 0`` over the state.
# (margin, op, label, step window or None): ``margin op 0`` must hold (in the window).
EngineCondition = Tuple[Expr, str, str, Optional[Tuple[float, float]]]
# A discrete plant: next-state expressions over env_names. A continuous plant: (right-hand sides,
# ODE variable names = states then inputs, input indices in the environment, control period,
# integration step, remainder estimate).
Plant = Union[Sequence[Expr], Tuple[Sequence[Expr], Sequence[str], Sequence[int], float, float, float]]
# A stage's component: a network, or expressions over named inputs.
Component = Union[Network, Tuple[Sequence[Expr], Sequence[str]]]

class ClosedLoop:
    """A perception-control loop for the cell engine. ``stages``: (component, indices of its inputs
    in the environment = state ++ stage outputs)."""

    def __init__(
        self,
        state_names: Sequence[str],
        stages: Sequence[Tuple[Component, Sequence[int]]],
        env_names: Sequence[str],
        plant: Plant,
        safe: Sequence[EngineCondition],
        goal: Optional[EngineCondition],
        goal_within: bool,
        steps: int,
    ) -> None: ...

def eval_float(
    exprs: Sequence[Expr], names: Sequence[str], points: NDArray[np.float64], parameters: Optional[Mapping[int, Sequence[float]]] = None
) -> NDArray[np.float64]:
    """Float evaluation of ``exprs`` on the rows of ``points`` (N x len(names)) -> N x len(exprs);
    ``parameters`` maps a parameter's id to its value in each row (others take their midpoint)."""

def eval_interval(exprs: Sequence[Expr], names: Sequence[str], bounds: Bounds) -> list[Tuple[float, float]]:
    """Interval evaluation over a box."""

def taylor_models(exprs: Sequence[Expr], names: Sequence[str], bounds: Bounds, order: int = 6, cutoff: float = 0.0) -> TaylorModels:
    """Taylor models of expressions over a box (each variable mapped affinely onto [-1, 1])."""

def parse_condition(text: str) -> Condition:
    """Parses Flow*'s constraint syntax ``lhs <= rhs`` into a Condition."""

def flowpipe(
    names: Sequence[str],
    rhs: Sequence[Expr],
    init: Bounds,
    t_end: float,
    step: Union[float, Tuple[float, float]],
    order: Union[int, Tuple[int, int]],
    cutoff: float = 1e-10,
    remainder: Optional[Sequence[float]] = None,
    precondition: str = "identity",
    refinements: int = 30,
    symbolic_queue: int = 100,
    progress: Optional[Callable[..., Any]] = None,
) -> FlowpipeResult:
    """A validated flowpipe of ``d names / dt = rhs`` from ``init`` to ``t_end``; ``step`` fixed or
    (min, max) adaptive, ``order`` fixed or (min, max) adaptive."""

class HybridRun:
    """A hybrid automaton's reach set: its segments per mode and its states at the horizon, over
    the automaton's variables and the clock ``time`` (the last)."""

    @property
    def names(self) -> list[str]: ...
    def segments(self) -> list[Tuple[int, float, float, list[Tuple[float, float]]]]:
        """Per segment: (mode index, t0, t1, [(lo, hi) per variable])."""
    def finals(self) -> list[Tuple[int, list[Tuple[float, float]]]]:
        """Per state at the horizon: (mode index, [(lo, hi) per variable])."""
    @property
    def failure(self) -> Optional[str]: ...
    @property
    def aggregations(self) -> int: ...

def hybrid_reach(
    names: Sequence[str],
    modes: Sequence[Tuple[str, Sequence[Expr], Sequence[Tuple[Expr, str]]]],
    jumps: Sequence[Tuple[int, Optional[int], Sequence[Tuple[Expr, str]], Optional[Sequence[Expr]], bool]],
    start: int,
    init: Bounds,
    t_end: float,
    step: Union[float, Tuple[float, float]],
    order: Union[int, Tuple[int, int]],
    cutoff: float,
    remainder: Sequence[float],
    max_jumps: int,
    max_branches: int,
    box_at_jumps: bool,
) -> HybridRun:
    """The reach set of the automaton from the box ``init`` in mode ``start`` up to ``t_end`` and
    ``max_jumps`` jumps, Flow*'s way; with ``box_at_jumps`` the state is boxed at every jump."""

class CellSettings:
    """How each cell is verified; every keyword left out takes the engine's default (Rust's
    ``CellSettings::default()``, the one source of them)."""

    def __init__(
        self,
        *,
        order: Optional[int] = None,
        cutoff: Optional[float] = None,
        method: Optional[str] = None,
        timeout: Optional[float] = None,
        nn_order: Optional[int] = None,
        blow_up_width: Optional[float] = None,
        max_splits: Optional[int] = None,
        max_redone: Optional[float] = None,
        rebox: Optional[bool] = None,
        state_symbols: Optional[bool] = None,
    ) -> None: ...
    @property
    def order(self) -> int: ...
    @property
    def cutoff(self) -> float: ...
    @property
    def method(self) -> str: ...
    @property
    def timeout(self) -> Optional[float]: ...
    @property
    def nn_order(self) -> int: ...
    @property
    def blow_up_width(self) -> float: ...
    @property
    def max_splits(self) -> int: ...
    @property
    def max_redone(self) -> Optional[float]:
        """Runs' steps the splits that restart may compute again before the cell is given up (None: no bound)."""
    @property
    def rebox(self) -> bool: ...
    @property
    def state_symbols(self) -> bool: ...

def _cell_settings(kwargs: Mapping[str, Any]) -> CellSettings:
    """``CellSettings(**kwargs)`` for unpickling."""

class StepCounter:
    """The deepest step of the cells running with it, readable while they run."""

    def __init__(self) -> None: ...
    def get(self) -> int: ...
    def reset(self) -> None: ...

class CellOutcome:
    """What verifying a cell found; picklable, so it comes back from executor workers as it is."""

    def __init__(
        self,
        verdict: str,
        reason: Optional[str],
        steps_done: int,
        deepest_step: int,
        boxes: Sequence[Bounds],
        seconds: float,
        nn_seconds: float,
        branches: int,
        steps_redone: int,
        split: Optional[int],
    ) -> None: ...
    @property
    def verdict(self) -> str:
        """One of "verified", "unknown", "violated"."""
    @property
    def reason(self) -> Optional[str]: ...
    @property
    def steps_done(self) -> int:
        """Steps completed by the whole cell: the boxes cover steps 0..steps_done."""
    @property
    def deepest_step(self) -> int:
        """The deepest step any piece of the cell reached."""
    @property
    def boxes(self) -> list[list[Tuple[float, float]]]:
        """The state box of each step, step 0 first."""
    @property
    def seconds(self) -> float: ...
    @property
    def nn_seconds(self) -> float: ...
    @property
    def branches(self) -> int: ...
    @property
    def steps_redone(self) -> int:
        """Steps computed again because a lost piece was split at an earlier step."""
    @property
    def split(self) -> Optional[int]:
        """The state the engine would have split next (an index into the state names); for a
        verified cell, the one it split most, if any."""
    def __reduce__(self) -> Tuple[Any, Tuple[Any, ...]]: ...

def verify_cells(
    problem: ClosedLoop,
    cells: Sequence[Bounds],
    done: Callable[[int, CellOutcome], Optional[bool]],
    settings: Optional[CellSettings] = None,
    workers: Optional[int] = None,
    progress: Optional[StepCounter] = None,
) -> None:
    """Runs ``cells`` ((lo, hi) per state variable) with ``settings``; ``done(index, outcome)`` is
    called as each cell finishes; returning False (or raising) stops starting new cells."""
