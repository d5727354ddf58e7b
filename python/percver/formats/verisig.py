"""Verisig 2.0 closed-loop models: Flow* ``hybrid reachability`` files with DNN modes, read.

:func:`read` returns the file as a hybrid automaton (:class:`Automaton`: variables, settings,
modes with their ODEs and invariants, jumps with guards and resets, the initial set, the unsafe
sets) with every expression an AST and every construct's position, so errors name file, line
and column. It does not interpret the model: :mod:`percver.translation` turns it into a percver
closed loop. The syntax is :mod:`percver.formats.flowstar_syntax`'s, shared with the Flow* readers.
"""

from __future__ import annotations

from percver.formats.flowstar_syntax import Automaton, Source, model_kind, parse

__all__ = ["read"]


def read(path: str) -> Automaton:
    """The model file as a hybrid automaton, untranslated; ``percver.ParseError`` names file,
    line and column of anything that is not Verisig's Flow* syntax. Verisig's integration
    settings (steps, orders, remainder, output) are kept as text: percver chooses its own."""
    src = Source.read(path, "Verisig model")
    kind, pos = model_kind(src)
    if kind == "continuous":
        raise src.error(
            pos, "a continuous model: read it with percver.formats.load_flowstar; load_verisig needs 'hybrid reachability' with DNN modes"
        )
    if kind != "hybrid":
        raise src.error(pos, "expected 'hybrid reachability { ... }' at the top (a Verisig/Flow* hybrid model)")
    aut = parse(src)
    if aut.settings.time is None:
        raise src.error(pos, "the setting block gives no 'time' horizon; add 'time T' to it")
    return aut
