"""``pv.verify``: a closed loop's property proved cell by cell over an initial set.

The modules, in the order a cell meets them:

- :mod:`~percver.verification.solve`: :func:`verify`, :func:`verify_parts` and :class:`Part`, the entry points;
- :mod:`~percver.verification.property`: the property (safe, goal, within) as the engine and float runs judge it;
- :mod:`~percver.verification.splitters`: how the initial set is cut into cells and unknown cells cut again (``splitter=``);
- :mod:`~percver.verification.journal`: resumable campaigns (append-only JSONL, problem fingerprints);
- :mod:`~percver.verification.campaign`: cells flowing through probe, engine and falsification, locally or on executors;
- :mod:`~percver.verification.executors`: cells on Dask or any ``concurrent.futures`` executor, the problem pickled once;
- :mod:`~percver.verification.falsify`: float runs that look for a counterexample;
- :mod:`~percver.verification.domains`: where a set leaves the input domain of a network stage;
- :mod:`~percver.verification.results`: :class:`Cell`, :class:`Counterexample`, :class:`Result`.
"""

from percver.verification.domains import DomainWarning
from percver.verification.journal import JournalError, JournalWarning
from percver.verification.results import Cell, Counterexample, Result
from percver.verification.solve import DEFAULTS, Part, verify, verify_parts
from percver.verification.splitters import Adaptive, Bisection, Grid

__all__ = [
    "Adaptive",
    "Bisection",
    "Cell",
    "Counterexample",
    "DEFAULTS",
    "DomainWarning",
    "Grid",
    "JournalError",
    "JournalWarning",
    "Part",
    "Result",
    "verify",
    "verify_parts",
]
