"""Symbolic expressions: variables, operators and functions that build the Rust ``Expr`` DAG.

One expression evaluates on floats (simulation, falsification), on intervals and on Taylor
models (verification), so the model that is simulated is the model that is verified.
"""

from __future__ import annotations

from typing import Iterable, Mapping, Sequence, Union

import numpy as np

from percver._core import Condition, Expr
from percver._core import eval_float as _eval_float
from percver._core import eval_interval as _eval_interval
from percver._core import taylor_models as _taylor_models
from percver.errors import InputError

Number = Union[int, float]
ExprLike = Union[Expr, Number, str]

__all__ = [
    "Expr",
    "Condition",
    "variables",
    "as_expr",
    "parse",
    "name_of",
    "sin",
    "cos",
    "tan",
    "atan",
    "exp",
    "log",
    "sqrt",
    "tanh",
    "sigmoid",
    "abs_",
    "sign",
    "where",
    "clip",
    "minimum",
    "maximum",
    "uncertain",
    "evaluate",
    "bounds",
]


def variables(names: str) -> Union[Expr, tuple]:
    """``x, v = variables("x v")``; a single name returns a single variable."""
    parts = names.replace(",", " ").split()
    if not parts:
        raise InputError("variables() needs at least one name, e.g. variables('x v')")
    made = tuple(Expr.var(p) for p in parts)
    return made[0] if len(made) == 1 else made


def as_expr(value: ExprLike) -> Expr:
    """Numbers become constants, strings are parsed in Flow* syntax."""
    if isinstance(value, Expr):
        return value
    if isinstance(value, str):
        return Expr.parse(value)
    if isinstance(value, (int, float, np.floating, np.integer)):
        return Expr.constant(float(value))
    raise InputError(f"cannot use {type(value).__name__} as an expression; use a number, a string or pv.variables(...)")


def parse(text: str) -> Expr:
    return Expr.parse(text)


def name_of(key: Union[Expr, str]) -> str:
    """The variable name of a dict key given as a variable or a string."""
    if isinstance(key, str):
        return key
    if isinstance(key, Expr) and key.name() is not None:
        return key.name()
    raise InputError(f"{key!r} is not a variable; use a variable from pv.variables(...) or its name")


def _apply(name: str):
    def f(x: ExprLike) -> Expr:
        return Expr.apply(name, as_expr(x))

    f.__name__ = name
    f.__doc__ = f"{name}(x) as an expression (sound on sets: Taylor-model remainder or interval image)."
    return f


sin = _apply("sin")
cos = _apply("cos")
tan = _apply("tan")
atan = _apply("atan")
exp = _apply("exp")
log = _apply("log")
sqrt = _apply("sqrt")
tanh = _apply("tanh")
sigmoid = _apply("sigmoid")
abs_ = _apply("abs")
abs_.__doc__ = "|x| as an expression (``pv.abs``): on sets, the image of the side(s) of 0 the set covers."


def sign(x: ExprLike) -> Expr:
    """-1, 0 or 1 by the sign of ``x`` (``pv.sign``): two nested ``where``, so a set on one side
    of 0 maps to that side's constant and a set that straddles 0 branches (or takes the hull
    [-1, 1]), as every ``where`` does."""
    x = as_expr(x)
    return Expr.select(x > 0.0, Expr.constant(1.0), Expr.select(x < 0.0, Expr.constant(-1.0), Expr.constant(0.0)))


def where(condition: Condition, then: ExprLike, otherwise: ExprLike) -> Expr:
    """Piecewise: ``then`` where the condition holds, else ``otherwise``."""
    if not isinstance(condition, Condition):
        raise InputError("where() needs a symbolic condition such as x >= 0 as its first argument")
    return Expr.select(condition, as_expr(then), as_expr(otherwise))


def minimum(a: ExprLike, b: ExprLike) -> Expr:
    return Expr.minimum(as_expr(a), as_expr(b))


def maximum(a: ExprLike, b: ExprLike) -> Expr:
    return Expr.maximum(as_expr(a), as_expr(b))


def clip(x: ExprLike, lo: ExprLike, hi: ExprLike) -> Expr:
    return minimum(maximum(x, lo), hi)


PER = ("step", "run")


def uncertain(lo: float, hi: float, per: str = "step") -> Expr:
    """A quantity known only to lie in [lo, hi].

    ``per="step"`` (the default) is a disturbance: it may take a new value each step (each
    evaluation), so a proof covers every sequence of values in the range. ``per="run"`` is a
    constant of the system that is not known exactly (a fitted friction, a mass): one value
    for a whole run, which ``verify`` carries as an extra Taylor-model variable with zero dynamics,
    so its reach sets keep the dependency on it and are tighter. Simulations and
    counterexamples draw one value per run for both unless given one per step
    (:meth:`ClosedLoop.simulate`).
    """
    if per not in PER:
        raise InputError(
            f"uncertain(..., per={per!r}): use per='step' (a disturbance, new each step) or per='run' (a constant of the system)"
        )
    return Expr.uncertain(float(lo), float(hi), per == "run")


def held_parameters(e: Union[ExprLike, Sequence[ExprLike]]) -> list:
    """The uncertain parameters held over a run (``uncertain(..., per="run")``) that ``e`` reads, as
    ``(id, lo, hi)``, each once."""
    found = {}
    for x in _exprs(e)[0]:
        for kind, held, values, _, name in x.__reduce__()[1][0]:
            if kind == 1 and held:
                found.setdefault(int(name), (int(name), values[0], values[1]))
    return list(found.values())


def _exprs(e: Union[ExprLike, Sequence[ExprLike]]) -> tuple[list[Expr], bool]:
    if isinstance(e, (list, tuple)):
        return [as_expr(x) for x in e], False
    return [as_expr(e)], True


def evaluate(e: Union[ExprLike, Sequence[ExprLike]], values: Mapping[str, Iterable[float]]) -> np.ndarray:
    """Float evaluation on batches: ``values`` maps names to equally long arrays."""
    exprs, single = _exprs(e)
    names = list(values)
    columns = [np.atleast_1d(np.asarray(values[n], dtype=float)) for n in names]
    if len({len(c) for c in columns}) > 1:
        raise InputError("evaluate(): all value arrays must have the same length")
    points = np.column_stack(columns) if columns else np.zeros((1, 0))
    out = _eval_float(exprs, names, np.ascontiguousarray(points))
    return out[:, 0] if single else out


def bounds(e: Union[ExprLike, Sequence[ExprLike]], box, *, method: str = "taylor", order: int = 6):
    """Sound range of expression(s) over a box: ``method`` is "interval" or "taylor" (LDB-refined)."""
    from percver.sets import Box

    b = Box.coerce(box)
    exprs, single = _exprs(e)
    if method == "interval":
        out = _eval_interval(exprs, b.names, b.bounds)
    elif method == "taylor":
        out = _taylor_models(exprs, b.names, b.bounds, order).range()
    else:
        raise InputError(f"unknown bounds method '{method}' (use 'interval' or 'taylor')")
    return out[0] if single else out
