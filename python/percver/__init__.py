"""percver: data-driven modeling and formal verification of perception-based autonomous systems."""

from percver import _core
from percver.errors import (
    BlowUpError,
    DomainError,
    InputError,
    MeasurementError,
    NetworkFormatError,
    ParseError,
    PercverError,
)

__version__ = _core.__version__
from percver.networks import Network, chain, load_network

from percver import sensors, validate
from percver.measurements import Measurements
from percver.validate import compare, diagnose
