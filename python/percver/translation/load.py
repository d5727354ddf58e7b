"""Reading a Verisig 2.0 model and its networks, and choosing the kind of plant it becomes."""

from __future__ import annotations

from typing import Sequence

from percver.formats import verisig
from percver.formats import load_network
from percver.networks import Network
from percver.translation.continuous import continuous_problem
from percver.translation.discrete import discrete_problem
from percver.translation.execution import Execution
from percver.translation.hybrid import hybrid_problem
from percver.translation.problem import VerisigProblem


def load_verisig(model_path: str, networks: Sequence = ()) -> VerisigProblem:
    """Reads a Verisig 2.0 model (``*_tmp.model`` / ``*_verisig.model``) and its networks.

    ``networks``: the ``.yml`` files (or loaded ``pv.Network`` objects) in the order the
    Verisig command line gives them; the k-th distinct ``DNN`` mode of the file uses the k-th.
    Raises ``percver.ParseError`` naming file, line and construct for anything it cannot
    translate faithfully.
    """
    aut = verisig.read(str(model_path))
    nets = [n if isinstance(n, Network) else load_network(str(n)) for n in networks]
    return translate(Execution(aut, nets))


def translate(ex: Execution) -> VerisigProblem:
    """The loop the model becomes: discrete without plant modes, hybrid with several, else continuous."""
    aut = ex.aut
    init_timers = ex.initial_timers()
    if aut.settings.max_jumps is None:
        ex.notes.append("no 'max jumps' setting; the horizon comes from 'time' alone")
    if ex.flow_mode is None:
        return discrete_problem(ex, init_timers)
    if len(ex.region) > 1:
        return hybrid_problem(ex, init_timers)
    return continuous_problem(ex, init_timers)
