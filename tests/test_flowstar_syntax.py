"""The one Flow* front end (percver.formats.flowstar_syntax): its printer reads back, it agrees
with the Rust core's parser (pv.parse) on random expressions and on what both refuse, and its
errors name file, line and column."""

import random
import re

import numpy as np
import pytest

import percver as pv
from percver.formats import flowstar_syntax as syntax

NAMES = ["x", "y", "v_1"]


def random_ast(rng: random.Random, depth: int) -> tuple:
    """An AST of the shapes the parser builds (literals are non-negative: a sign is a 'neg')."""
    if depth == 0 or rng.random() < 0.2:
        pick = rng.random()
        if pick < 0.4:
            return ("var", rng.choice(NAMES), 0)
        if pick < 0.9:
            return ("num", rng.choice([0.0, 1.0, 2.5, 1e-7, 3e21, 0.1, 123.456]))
        lo = rng.uniform(-2, 1)
        return ("interval", lo, lo + rng.choice([0.0, 0.5]))
    sub = lambda: random_ast(rng, depth - 1)  # noqa: E731
    kind = rng.choice(["neg", "bin", "bin", "bin", "pow", "call", "min", "max", "where"])
    if kind == "neg":
        return ("neg", sub())
    if kind == "bin":
        return ("bin", rng.choice("+-*/"), sub(), sub())
    if kind == "pow":
        return ("pow", sub(), ("num", rng.choice([2.0, 3.0, -1.0, 0.5, -2.5])))
    if kind == "call":
        return ("call", rng.choice(sorted(set(syntax.FUNCTIONS.values()))), sub(), 0)
    if kind in ("min", "max"):
        return (kind, sub(), sub())
    return ("where", sub(), rng.choice(["<=", ">=", "<", ">"]), sub(), sub(), sub())


def unplaced(ast):
    """The AST without file positions."""
    if ast[0] in ("var", "call"):
        return ast[:-1] if ast[0] == "var" else (ast[0], ast[1], unplaced(ast[2]))
    return tuple(unplaced(a) if isinstance(a, tuple) else a for a in ast)


EXPRESSIONS = [syntax.text(random_ast(random.Random(seed), 5)) for seed in range(300)]


@pytest.mark.parametrize("seed", range(300))
def test_printed_expressions_read_back(seed):
    ast = random_ast(random.Random(seed), 5)
    assert unplaced(syntax.parse_expression(syntax.text(ast))) == unplaced(ast)


def test_the_rust_parser_builds_the_same_expressions():
    for source in EXPRESSIONS + ["-x^2", "x^-1", "2e-1*x + .5", "clip(x, -1, 1)", "x - y - 1", "x / y / 2", "sin(x)^2 + cos(x)^2"]:
        ours = syntax.to_expr(syntax.parse_expression(source))
        assert str(ours) == str(pv.parse(source)), source
    for alias, name in (("ln(x)", "log(x)"), ("arctan(+x)", "atan(x)"), ("[+1, 2] * x", "[1.0, 2.0] * x")):
        assert str(syntax.to_expr(syntax.parse_expression(alias))) == str(pv.parse(name))


def test_percvers_printed_expressions_read_back_with_their_values():
    x, y = pv.variables("x y")
    rng = np.random.default_rng(0)
    exprs = [
        pv.where(x >= 0.5 * y, pv.clip(x * y - 1e-7, -1.5, 2), -(y**3) / (1 + x * x)),
        pv.exp(pv.sin(x) - pv.abs_(y)) + pv.sqrt(1 + x**2) ** 0.5 - pv.tanh(y) * pv.sigmoid(x),
        pv.minimum(x, 3e-12) - pv.maximum(-y, 1e21) + pv.atan(x) ** -2,
    ]
    points = {"x": rng.uniform(-2, 2, 50), "y": rng.uniform(-2, 2, 50)}
    for e in exprs:
        back = syntax.to_expr(syntax.parse_expression(syntax.text(syntax.parse_expression(repr(e)))))
        np.testing.assert_array_equal(pv.evaluate(back, points), pv.evaluate(e, points))


@pytest.mark.parametrize(
    "source, words",
    [
        ("x^2^3", "chained '^'"),
        ("x^y", "exponent"),
        ("x * 1e999", "'1e999' overflows to infinity"),
        ("foo(x)", "unknown function 'foo'"),
        ("min(x)", "min takes 2 argument(s), got 1"),
        ("x $ y", "unexpected character '$'"),
        ("(x + y", "')'"),
        ("", "empty expression"),
        ("[2, 1]", "empty interval"),
        ("1.2.3", "unexpected"),
        ("where(x = 1, x, y)", "comparison"),
    ],
)
def test_both_parsers_refuse_the_same_text(source, words):
    with pytest.raises(pv.ParseError, match=re.escape(words)):
        syntax.parse_expression(source)
    with pytest.raises(pv.PercverError):
        pv.parse(source)


def hybrid(tmp_path, ode: str, settings: str = "fixed steps 0.1\n  time 1\n  fixed orders 4"):
    path = tmp_path / "m.model"
    path.write_text(
        "hybrid reachability\n{\n state var x, t\n setting\n {\n  "
        + settings
        + "\n }\n modes\n {\n  a\n  {\n   nonpoly ode\n   {\n    x' = "
        + ode
        + "\n    t' = 1\n   }\n   inv { t <= 1 }\n  }\n }\n jumps\n {\n }\n init\n {\n  a\n  {\n   x in [0, 1]\n   t in [0, 0]\n  }\n }\n}\n"
    )
    return str(path)


def test_a_model_reads_the_same_in_every_reader(tmp_path):
    path = hybrid(tmp_path, "clip(-x^2, -1, 1) + where(x > t, 1, 0) - ln(1 + t)")
    model = pv.formats.load_flowstar(path)
    want = pv.parse("clip(-x^2, -1, 1) + where(x > t, 1, 0) - log(1 + t)")
    assert str(model.plant.rhs_of("a")[0]) == str(want)
    aut = pv.formats.verisig.read(path)
    values = {"x": np.array([-0.5, 0.3, 2.0]), "t": np.array([0.1, 0.5, 0.0])}
    np.testing.assert_array_equal(pv.evaluate(syntax.to_expr(aut.modes["a"].ode["x"]), values), pv.evaluate(want, values))


@pytest.mark.parametrize(
    "ode, settings, where, words",
    [
        ("x + foo(t)", None, (16, 14), "unknown function 'foo'"),
        ("x + * t", None, (16, 14), "expected an expression, found '*'"),
        ("x * [1, 0]", None, (16, 14), "empty interval"),
        ("x", "fixed steps 0.1\n  time 1\n  fixed orders 4\n  warp 9", (9, 3), "unsupported setting 'warp 9'"),
        ("x", "fixed steps abc\n  time 1", (6, 15), "expected a number for the step, found 'abc'"),
        ("x", "time 1\n  fixed orders 4", (4, 2), "the setting block gives no step: add 'fixed steps h'"),
    ],
)
def test_errors_name_file_line_and_column(tmp_path, ode, settings, where, words):
    path = hybrid(tmp_path, ode, *([settings] if settings else []))
    with pytest.raises(pv.ParseError, match=rf"m.model, line {where[0]}, column {where[1]}: {re.escape(words)}"):
        pv.formats.load_flowstar(path)
