"""percver: data-driven modeling and formal verification of perception-based autonomous systems."""

from percver import _core
from percver.errors import (
    BlowUpError,
    DomainError,
    InputError,
    MeasurementError,
    NetworkDomainError,
    NetworkFormatError,
    ParseError,
    PercverError,
)

__version__ = _core.__version__

from percver import formats
from percver.expr import (
    Condition,
    Expr,
    abs_,
    atan,
    bounds,
    clip,
    cos,
    evaluate,
    exp,
    log,
    maximum,
    minimum,
    parse,
    sigmoid,
    sign,
    sin,
    sqrt,
    tan,
    tanh,
    uncertain,
    variables,
    where,
)
from percver.flowpipe import Flowpipe, HybridFlowpipe, flowpipe, hybrid_flowpipe
from percver.sets import Box
from percver.properties import all_of, any_of, during
from percver.systems import ClosedLoop, Continuous, Discrete, Hybrid, Jump, Mode, Stage
from percver.perception import Perception
from percver.verification import Adaptive, Bisection, DomainWarning, Grid, Part, Result, verify, verify_parts

min = minimum  # noqa: A001 - the design's names pv.min / pv.max, like numpy's
max = maximum  # noqa: A001
abs = abs_  # noqa: A001 - pv.abs, like numpy's
from percver.networks import Network, chain
from percver.formats import load_network, save_network
from percver.translation import VerisigProblem, load_verisig

from percver import noise, sensors, validate
from percver.measurements import Measurements
from percver.validate import compare, diagnose


def __getattr__(name: str):
    # The case studies are built from the library, not part of it: ``pv.cases`` loads on first use.
    if name == "cases":
        import importlib

        return importlib.import_module("percver.cases")
    raise AttributeError(f"module 'percver' has no attribute {name!r}")
