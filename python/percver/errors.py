"""The exception types of percver.

Every error a user can trigger is one of these, never a bare ``Exception`` or a Rust panic.
The Rust core raises them too (``crates/percver-py/src/error.rs`` maps each Rust error
variant to one class here), so ``except percver.PercverError`` catches everything.
"""


class PercverError(Exception):
    """Base class of every error raised by percver."""


class InputError(PercverError, ValueError):
    """An argument is malformed: empty or NaN box, order 0, negative step, unknown name."""


class ParseError(PercverError, ValueError):
    """A model, expression or network file cannot be read; the message names file and place."""


class DomainError(PercverError, ArithmeticError):
    """A function was applied outside its domain on a set (log of a negative interval, ...)."""


class NetworkDomainError(DomainError):
    """A set reaches inputs outside the domain a network was trained on (``verify(strict=True)``)."""


class BlowUpError(PercverError, ArithmeticError):
    """A flowpipe or reach set could not be enclosed: the message gives the time reached."""


class NetworkFormatError(ParseError):
    """A network file uses an unsupported operator, shape or value."""


class MeasurementError(InputError):
    """Measurement data is malformed (NaN rows, shape mismatch, unsorted time, ...)."""


class MissingFileError(InputError, FileNotFoundError):
    """A file named by the user does not exist (also a ``FileNotFoundError``)."""


class MissingDependencyError(PercverError, ImportError):
    """An optional dependency (torch, gymnasium, pillow, matplotlib) is not installed; the message names the extra."""
