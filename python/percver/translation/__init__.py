"""Verisig 2.0 closed-loop models translated into percver closed loops.

Verisig encodes one control period as a chain of zero-time modes and jumps: resets compute
helper variables, modes named ``DNN...`` evaluate a network on ``_f1.._fN`` (outputs come back
in ``_f1..``), modes named ``_op_i_j...`` apply ``var_i := op(var_j)`` (op: cos, sin, tan, div
= 1/x, arc = atan, sqrt, sec), ``_reset_`` modes flow for a fixed time with constant dynamics
(a discrete update written as an ODE), and a ``clock`` plus counters (``k``, ``worldtime``)
drive the step structure. :func:`load_verisig` reads the file (:mod:`percver.formats.verisig`)
and executes that chain symbolically once, so one period becomes expressions over the true
plant states: a ``pv.Discrete`` update when no mode integrates real dynamics, a ``pv.Continuous``
plant (the one flowing mode) whose inputs are computed by the stages, or a ``pv.Hybrid`` plant
when the period flows through several plant modes. Branching jumps become ``where`` chains, so the step is the same
function Verisig explores branch by branch.

Properties come from the ``unsafe`` block and the jumps into its modes: a guard without
counters is checked at every step (and along the flowpipe for continuous plants); a guard that
fires only at the horizon (``k >= 150``, ``worldtime = 7``) becomes a goal at the final step; an
absorbing mode that ends the run early (Mountain Car's goal mode) becomes a ``within`` goal.
Like Flow*, no flow starts at the time horizon, so guards holding only from then on never fire.

Assumptions (true of Verisig's generated models; anything else is refused or noted):
- jumps leaving one mode have exclusive guards up to their boundaries; on a boundary the
  ``where`` takes the branch tested first (Verisig takes both: a measure-zero difference), and
  two jumps without state guards leaving one mode together are refused;
- a guard on a single path is not tested and state invariants are ignored: both keep runs
  Verisig would block, an over-approximation;
- jumps out of a flowing mode fire at the end of its dwell (``clock = c``);
- a continuous plant cannot jump: a branch resetting plant states is dropped and "its guard
  never holds" becomes a safety obligation (F1/10's corridor rotation at ``y1 >= 20``).

The package, one concept per module: ``values`` (symbolic values), ``analysis`` (what each
variable and mode is), ``execution`` and ``branches`` (one period run symbolically), ``timing``
(steps and horizons), ``properties`` and ``conditions`` (the property), ``stages`` (the loop's
stages), ``discrete`` / ``continuous`` / ``hybrid`` (the three kinds of plant), ``problem``
(the result) and ``load`` (the entry point).
"""

from percver.translation.load import load_verisig
from percver.translation.problem import VerisigProblem

__all__ = ["load_verisig", "VerisigProblem"]
