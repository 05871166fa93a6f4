"""Fuzzing the compiler front end: whatever the text, ``compile_spec`` either compiles or raises a SpecError.

Derandomized and database-less, so CI runs the same examples every time; sized to stay well under 30 s.
"""

from __future__ import annotations

import json
import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from myriad.compiler import SpecError, SpecErrors, compile_spec


def fuzz(n: int):
    return settings(max_examples=n, derandomize=True, database=None, deadline=None, print_blob=False,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

VALID = """\
schema: 1
name: fuzz
title: Fuzz
description: A minimal spec for fuzzing.
parameters:
  k: {value: 0.5, learnable: true, guess: 0.4, description: decay rate}
definitions:
  d: k*x
states:
  x: {initial: 1, bounds: [0, 10], description: level}
controls:
  u: {bounds: [-1, 1], description: input}
dynamics:
  x: EXPR
cost:
  sense: minimize
  running: x**2 + u**2
horizon: 1
"""
DYNAMICS_LINE = VALID.splitlines().index("  x: EXPR") + 1
# Schema 2: a free final time and path constraints, the fuzzed expression in a path constraint.
VALID2 = VALID.replace("schema: 1", "schema: 2").replace("  x: EXPR", "  x: -d + u").replace(
    "horizon: 1\n", "horizon: {free: true, guess: 2, bounds: [0.5, 10]}\n"
    "path_constraints:\n"
    "  cap: {expression: PATH, bounds: [-.inf, 2], description: a cap}\n"
    "  band: {expression: x*u, bounds: [-1, 1]}\n")
PATH_LINE = VALID2.splitlines().index("  cap: {expression: PATH, bounds: [-.inf, 2], description: a cap}") + 1
# Schema 3: uncertainty, with a slot for each kind of number it holds (a distribution, a scenario, alpha, samples,
# a noise level); DEFAULTS fill the slots a test leaves alone.
VALID3 = VALID.replace("schema: 1", "schema: 3").replace("  x: EXPR", "  x: -d + u").replace(
    "guess: 0.4, description", "guess: 0.4, bounds: [0, .inf], uncertain: {DIST: [0.4, HI]}, description") + (
    "scenarios: [{k: 0.45}, {k: SCENARIO}]\n"
    "robust: {objective: OBJECTIVE}\n"
    "noise: {process: {x: SIGMA}, observation: {x: 0.01}}\n")
DEFAULTS = {"DIST": "uniform", "HI": "0.6", "SCENARIO": "0.55", "OBJECTIVE": "{cvar: 0.9}", "SIGMA": "0.1"}
ONE_LINE = re.compile(r"fuzz\.yaml:(\d+):(\d+): error: \S.*\Z", re.S)


def _compile(text: str):
    """Compile; on failure check the error is a well-formed SpecError and return it, else return None."""
    try:
        compiled = compile_spec(text, "fuzz.yaml")
    except SpecErrors as exc:
        assert exc.errors
        return exc.errors[0]
    except SpecError as exc:
        line = exc.one_line()
        assert ONE_LINE.match(line), line
        assert "\n" not in line.split(": error: ", 1)[0]
        assert 1 <= exc.loc.line <= max(len(text.splitlines()), 1) + 1, line
        assert exc.loc.col >= 1, line
        str(exc)  # the caret rendering must not fail either
        return exc
    compile(compiled.text, "fuzz.py", "exec", dont_inherit=True)  # parsed, never run
    return None


# -- (a) arbitrary text ------------------------------------------------------------------------------------------

YAMLISH = [
    "schema: 1\n", "name: fuzz\n", "title: t\n", "description: d\n", "states:\n", "controls:\n", "dynamics:\n",
    "cost:\n", "horizon: 1\n", "  x: {initial: 1}\n", "  u: {}\n", "  x: u\n", "  sense: minimize\n",
    "  running: u**2\n", "parameters:\n", "  k: 0.5\n", "definitions:\n", "reference: {published: 1}\n",
    ":", ": ", "- ", "-", "{", "}", "[", "]", ",", "&a ", "*a", "&b [*a, *a]", "!!python/object/apply:os.system ",
    "!!binary ", "!", "? ", "|\n", ">\n", "---\n", "...\n", "%YAML 1.1\n", "#", "'", '"', "\\", "\t", "  ", "\n",
    "\r\n", "\x00", "\x07", "\ufeff", "\ud800", "\u2028", "1e999", ".inf", "-.inf", ".nan", "null", "~", "yes", "no",
    "2024-13-45", "0x1F", "1:30", "1" * 400, "9**9**9", "__import__('os')", "x.__class__", "lambda: 1", "x[0]",
    "schema: 2\n", "horizon: {free: true, guess: 2, bounds: [0.5, 10]}\n", "path_constraints:\n",
    "  c: {expression: x + u, bounds: [-.inf, 2]}\n", "free: false", "guess: .nan", "bounds: [.inf, -.inf]",
    "expression: ", "{free: true}", "[0, 1]",
    "schema: 3\n", "scenarios: [{k: 0.5}]\n", "robust: {objective: mean}\n", "noise: {process: {x: 0.1}}\n",
    "  k: {value: 0.5, bounds: [0, .inf], uncertain: {uniform: [0.4, 0.6]}}\n", "uncertain: {normal: [0, 1]}",
    "{cvar: 0.9}", "samples: 0", "observation: {x: -1}",
]
yamlish_text = st.lists(st.one_of(st.sampled_from(YAMLISH), st.text(max_size=8)), max_size=40).map("".join)


@pytest.mark.slow
@fuzz(400)
@given(st.one_of(st.text(max_size=300), yamlish_text))
def test_arbitrary_text_raises_only_spec_errors(text):
    _compile(text)


@fuzz(300)
@given(st.data())
def test_mutated_valid_spec_raises_only_spec_errors(data):
    """Insert, replace or delete a fragment anywhere in a valid spec: reaches deeper than random text does."""
    base = VALID.replace("EXPR", "-d + u")
    start = data.draw(st.integers(0, len(base)))
    end = data.draw(st.integers(start, min(len(base), start + 12)))
    fragment = data.draw(st.one_of(st.sampled_from(YAMLISH), st.text(max_size=6)))
    _compile(base[:start] + fragment + base[end:])


@pytest.mark.slow
@fuzz(200)
@given(st.data())
def test_mutated_schema2_spec_raises_only_spec_errors(data):
    """The same for the schema 2 fields: a free final time and path constraints."""
    base = VALID2.replace("PATH", "x + u")
    assert _compile(base) is None
    start = data.draw(st.integers(0, len(base)))
    end = data.draw(st.integers(start, min(len(base), start + 12)))
    fragment = data.draw(st.one_of(st.sampled_from(YAMLISH), st.text(max_size=6)))
    _compile(base[:start] + fragment + base[end:])


@pytest.mark.slow
@fuzz(200)
@given(st.data())
def test_mutated_schema3_spec_raises_only_spec_errors(data):
    """The same for the schema 3 fields: uncertain parameters, scenarios, robust and noise."""
    base = VALID3
    for slot, value in DEFAULTS.items():
        base = base.replace(slot, value)
    assert _compile(base) is None
    start = data.draw(st.integers(0, len(base)))
    end = data.draw(st.integers(start, min(len(base), start + 12)))
    fragment = data.draw(st.one_of(st.sampled_from(YAMLISH + SCHEMA3_VALUES), st.text(max_size=6)))
    _compile(base[:start] + fragment + base[end:])


SCHEMA3_VALUES = ["0", "-0.1", "1", "0.5", "2", "1e308", "1e999", "-.inf", ".inf", ".nan", "true", "null", "~", "''",
                  "[]", "[0.5]", "[0.1, 0.2, 0.3]", "{}", "{cvar: 0.5}", "{cvar: 1}", "{cvar: .nan}", "mean", "worst",
                  "cvar", "uniform", "normal", "lognormal", "choice", "gaussian", "1" * 400, "0x10", "2*k",
                  "__import__('os')", "'0.5'", "!!python/object/apply:os.system ['true']", "*a", "&a 1"]


@fuzz(200)
@given(st.dictionaries(st.sampled_from(sorted(DEFAULTS)), st.one_of(st.sampled_from(SCHEMA3_VALUES),
                                                                   st.text(max_size=6)), min_size=1))
def test_schema3_values_compile_or_raise_spec_error(values):
    """Whatever goes into the schema 3 slots, the spec compiles (and then its module holds numbers) or each error is
    a well-formed SpecError; nothing in these fields is evaluated."""
    text = VALID3
    for slot, default in DEFAULTS.items():
        text = text.replace(slot, values.get(slot, default))
    _compile(text)


# -- (b) grammar-aware expressions ---------------------------------------------------------------------------------

NAMES = ["x", "u", "k", "d", "t", "pi", "e", "inf", "nan", "y", "X", "__class__", "_x", "True", "None", "self",
         "jnp", "params", "lambda_"]
GOOD_FUNCS = ["exp", "log", "sqrt", "sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "abs", "sign",
              "atan2", "min", "max", "clip", "mod", "where", "piecewise"]
BAD_FUNCS = ["eval", "exec", "open", "getattr", "__import__", "print", "compile", "globals", "Symbol", "sympify", "jnp",
             "expo", "x", "pi", "math.sin", "jnp.exp", "(lambda: 1)"]
BINOPS = ["+", "-", "*", "/", "**", "^", "%", "//", "@", "<<", ">>", "&", "|"]
COMPARE = ["<", "<=", ">", ">=", "==", "!=", "is", "in", "not in"]
JUNK = [")", "(", ",", ":", "lambda:", "=", "[", "]", "{", "}", ";", "\\", "#", "'", '"', "`", "$", "!", "?", "@", ".",
        "...", "'s'", "f'{x}'", "b''", "1j", ":=", "*", "**", "yield", "await", "\t", " ", "\n", "\x00", "é"]

numbers = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.sampled_from(["0", "0.0", "1e-3", "1e999", "1e-999", "0x1F", "1_000", "00", "1.", ".5", "9" * 30, "2**4096",
                     "10**-400"]),
)
leaves = st.one_of(st.sampled_from(NAMES), numbers)


def _extend(children):
    pair = st.tuples(children, children)
    return st.one_of(
        st.tuples(children, st.sampled_from(BINOPS), children).map(lambda a: f"{a[0]} {a[1]} {a[2]}"),
        st.tuples(st.sampled_from(["-", "+", "not ", "~"]), children).map("".join),
        children.map(lambda a: f"({a})"),
        st.tuples(st.sampled_from(GOOD_FUNCS + BAD_FUNCS), st.lists(children, max_size=4)).map(
            lambda a: f"{a[0]}({', '.join(a[1])})"),
        st.tuples(children, st.sampled_from(COMPARE), children).map(lambda a: f"{a[0]} {a[1]} {a[2]}"),
        st.tuples(pair, st.sampled_from(["and", "or"])).map(lambda a: f"{a[0][0]} {a[1]} {a[0][1]}"),
        st.tuples(children, children, children).map(lambda a: f"where({a[0]} > {a[1]}, {a[1]}, {a[2]})"),
        st.tuples(children, children, children).map(lambda a: f"piecewise({a[0]} < 0, {a[1]}, {a[2]})"),
        st.tuples(children, children, children).map(lambda a: f"{a[0]} if {a[1]} else {a[2]}"),
        st.tuples(children, st.sampled_from(["__class__", "real", "evalf", "__mro__"])).map(lambda a: f"{a[0]}.{a[1]}"),
        pair.map(lambda a: f"{a[0]}[{a[1]}]"),
        pair.map(lambda a: f"max({a[0]}, {a[1]}, key={a[0]})"),
        st.tuples(children, st.sampled_from(JUNK), children).map("".join),
    )


expressions = st.recursive(leaves, _extend, max_leaves=12)


def _yaml_scalar(expr: str, style: str) -> str:
    if style == "plain":
        return expr
    if style == "single":
        return "'" + expr.replace("'", "''") + "'"
    return json.dumps(expr)  # a JSON string is a YAML double-quoted scalar


@pytest.mark.slow
@fuzz(400)
@given(expressions, st.sampled_from(["plain", "single", "double"]))
def test_grammar_expressions_compile_or_raise_spec_error(expr, style):
    text = VALID.replace("EXPR", _yaml_scalar(expr, style))
    error = _compile(text)
    if error is not None and style == "double":
        # Only the dynamics changed, and a quoted scalar stays on its line: the error must point there.
        assert error.loc.line == DYNAMICS_LINE, error.one_line()


@fuzz(200)
@given(expressions, st.sampled_from(["plain", "single", "double"]))
def test_grammar_path_constraints_compile_or_raise_spec_error(expr, style):
    # A flow mapping ends a plain scalar at `,` or `}`, so only quoted expressions are known to stay in the field.
    text = VALID2.replace("PATH", _yaml_scalar(expr, style))
    error = _compile(text)
    if error is not None and style == "double":
        assert error.loc.line == PATH_LINE, error.one_line()


@fuzz(200)
@given(st.lists(st.sampled_from(NAMES + GOOD_FUNCS + BAD_FUNCS + BINOPS + COMPARE + JUNK + ["1", "2.5", "(", ")"]),
                max_size=16))
def test_token_soup_compiles_or_raises_spec_error(tokens):
    _compile(VALID.replace("EXPR", json.dumps(" ".join(tokens))))


# -- found by fuzzing valid-leaning expressions: once failures in lowering, now each compiles or is a spec error --

FORMER_LOWERING_FAILURES = [
    # d/du sign(u) = 2*DiracDelta(u): derivatives are taken almost everywhere, so the delta is dropped.
    ("  x: EXPR", "  x: -k*x + sign(u)", "compiles"),
    ("  x: EXPR", "  x: -k*x + u*sign(x)", "compiles"),
    # A running cost piecewise in u: u* has no closed form, the module says so and still compiles.
    ("  running: x**2 + u**2", "  running: x**2 + where(u < 0, -u, 0)", "compiles"),
    # A condition holding atan2(0, u): sympy cannot decide it at u = 0; u* is reported as not derivable.
    ("  x: EXPR", "  x: piecewise(-1 < atan2(0, u), x, u)", "compiles"),
    # log(0) in one branch: a spec error at the dynamics, not a crash in the printer.
    ("  x: EXPR", "  x: -log(where(pi >= k, 0, u))", "error"),
]


@pytest.mark.parametrize("old,new,outcome", FORMER_LOWERING_FAILURES,
                         ids=[c[1].strip() for c in FORMER_LOWERING_FAILURES])
def test_former_lowering_failures(old, new, outcome):
    err = _compile(VALID.replace(old, new).replace("EXPR", "-d + u"))
    assert (err is None) == (outcome == "compiles"), err
