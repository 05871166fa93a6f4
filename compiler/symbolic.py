"""Pass 2, symbolic: the name-checked :class:`ProblemSpec` → :class:`SymbolicProblem` (sympy, the spec's own sense).

Declared names become real sympy symbols (``t`` is :data:`TIME`); every expression is parsed by the whitelisted grammar
of :mod:`.expressions` against the names it may use (path constraints, schema 2, like the dynamics); definitions are
inlined in order; and every constant field (parameter values, bounds, initial and final values, the horizon and a free
horizon's bounds, guesses) is evaluated to a float, recording which parameters the generated code will hold as numbers
(``structural_params``).
"""

from __future__ import annotations

import fractions
import math

import sympy

from .errors import ErrorLog, SpecError
from .expressions import FAILED, FUNCTIONS, ExpressionParser, wrap_floor, wrap_mod
from .schema import Expr, ProblemSpec, SymbolicProblem

# FUNCTIONS, ExpressionParser, wrap_mod and wrap_floor live in .expressions; re-exported for existing importers.
__all__ = ["FUNCTIONS", "TIME", "ExpressionParser", "to_symbolic", "wrap_floor", "wrap_mod"]

TIME = sympy.Symbol("t", real=True)


def _hint(kinds: str) -> str:
    return f"declare it under {kinds}"


def to_symbolic(spec: ProblemSpec, log: ErrorLog) -> SymbolicProblem:
    """Build sympy expressions for every expression and evaluate every constant field.

    Assumes :func:`compiler.checks.check_names` passed (names are valid and unique). Each field is built on its own:
    one that fails is recorded in ``log`` and is None in the result, a partial problem that the check pass reads
    (skipping what is None) before the pipeline stops.
    """
    params = tuple(sympy.Symbol(p.name, real=True) for p in spec.parameters)
    states = tuple(sympy.Symbol(s.name, real=True) for s in spec.states)
    controls = tuple(sympy.Symbol(c.name, real=True) for c in spec.controls)

    const_ns, param_values = _parameter_values(spec, log)
    numeric_params = {sym: sympy.Rational(fractions.Fraction(v)) for sym, v in zip(params, param_values)
                      if v is not None}
    full_ns, definitions = _definitions(spec, (*params, *states, *controls), log)

    expr_parser = ExpressionParser(full_ns, spec.lines, _hint("parameters:, states:, controls: or definitions:"))
    dynamics_by_state = {eq.name: log.attempt(expr_parser.parse, eq.expr) for eq in spec.dynamics}
    dynamics = tuple(dynamics_by_state.get(s.name) for s in spec.states)

    # The IR keeps the spec's own sense; lowering negates a payoff into minimisation form.
    running = log.attempt(expr_parser.parse, spec.running)
    terminal = log.attempt(expr_parser.parse, spec.terminal) if spec.terminal is not None else sympy.Integer(0)
    path = tuple(log.attempt(_path_expression, expr_parser, c.expr) for c in spec.path_constraints)

    # Constant fields: numbers, pi, inf, parameters at nominal values, parameter-only definitions.
    constant_ns = dict(const_ns)
    for name, e in definitions.items():
        if e is FAILED or (e.free_symbols <= set(params) and not e.free_symbols <= set(numeric_params)):
            constant_ns[name] = FAILED  # it failed, or uses a parameter that did
        elif e.free_symbols <= set(params):
            # Numerically (30 digits), not by exact substitution: `3**k` with k = 1e9 would build a huge integer.
            constant_ns[name] = e.evalf(30, subs=numeric_params)
    for name in full_ns:
        constant_ns.setdefault(name, None)  # declared but not constant: explained below
    cparser = _ConstantParser(constant_ns, spec.lines)
    fields = _constant_fields(spec, cparser, log)
    # The parameters these constants were evaluated with (directly or through a definition): the generated code
    # holds the numbers, so a new value of such a parameter at run time could not move them.
    used = set(cparser.used)
    for name in cparser.used:
        if name in definitions and definitions[name] is not FAILED:
            used |= {str(sym) for sym in definitions[name].free_symbols}
    structural = tuple(p.name for p in spec.parameters if p.name in used)
    # After `structural`: a guess is only a starting value, so the parameters it uses are not structural.
    guesses = tuple(None if p.guess is None else log.attempt(_constant, cparser, p.guess, finite=True)
                    for p in spec.parameters)

    return SymbolicProblem(
        spec=spec, states=states, controls=controls, params=params, time=TIME, dynamics=dynamics,
        running=running, terminal=terminal, param_values=tuple(param_values), guesses=guesses,
        structural_params=structural, path=path, **fields,
    )


def _constant_fields(spec: ProblemSpec, cparser: _ConstantParser, log: ErrorLog) -> dict:
    """Every constant field evaluated, as keyword arguments of :class:`SymbolicProblem` (None where one failed)."""

    def const(e: Expr | None, default: float | None, finite: bool) -> float | None:
        return default if e is None else log.attempt(_constant, cparser, e, finite=finite)

    # A free horizon's guess and bounds may read as infinite here: the check pass refuses them with the reason.
    free = spec.free_horizon
    return dict(
        x0=tuple(const(s.initial, math.nan, True) for s in spec.states),
        x_lower=tuple(const(s.lower, -math.inf, False) for s in spec.states),
        x_upper=tuple(const(s.upper, math.inf, False) for s in spec.states),
        u_lower=tuple(const(c.lower, -math.inf, False) for c in spec.controls),
        u_upper=tuple(const(c.upper, math.inf, False) for c in spec.controls),
        x_final=tuple(const(s.final, None, True) for s in spec.states),
        horizon=const(spec.horizon, None, free is None),
        horizon_bounds=None if free is None else (const(free.lower, math.nan, False),
                                                  const(free.upper, math.nan, False)),
        path_lower=tuple(const(c.lower, -math.inf, False) for c in spec.path_constraints),
        path_upper=tuple(const(c.upper, math.inf, False) for c in spec.path_constraints),
    )


def _definitions(spec: ProblemSpec, symbols: tuple, log: ErrorLog) -> tuple[dict, dict]:
    """The namespace of dynamics and costs (symbols, ``t``, definitions inlined in order; a definition may use any
    earlier one, so there are no cycles), and the definitions' expressions (FAILED where one failed)."""
    full_ns: dict = {str(s): s for s in symbols}
    full_ns["t"] = TIME
    definitions = {}
    def_parser = ExpressionParser(full_ns, spec.lines, _hint("parameters:, states:, controls: or definitions: (a "
                                                            "definition may use only definitions written above it)"))
    for d in spec.definitions:
        e = log.attempt(def_parser.parse, d.expr)
        definitions[d.name] = full_ns[d.name] = FAILED if e is None else e
    return full_ns, definitions


def _parameter_values(spec: ProblemSpec, log: ErrorLog) -> tuple[dict, list[float | None]]:
    """The parameters' values, evaluated in order (a value may use earlier parameters; None where one failed), and
    the namespace of exact rationals that constant fields are evaluated in."""
    const_ns: dict = {}
    param_values = []
    for p in spec.parameters:
        parser = ExpressionParser(const_ns, spec.lines,
                                  "a parameter value may use only numbers, pi and earlier parameters")
        value = log.attempt(_constant, parser, p.value, finite=True)
        const_ns[p.name] = FAILED if value is None else sympy.Rational(fractions.Fraction(value))
        param_values.append(value)
    return const_ns, param_values


def _path_expression(parser: ExpressionParser, e: Expr):
    """A path constraint's expression; writing the inequality itself is the usual slip, so say how to write it."""
    try:
        return parser.parse(e)
    except SpecError as exc:
        if "comparison" not in exc.message:
            raise
        hint = ("a path constraint is an expression with its limits in `bounds:`, e.g. `expression: x + u` and "
                "`bounds: [-.inf, 2]` for x + u <= 2")
        raise SpecError(f"{exc.message}; {hint}", exc.loc, exc.source_line) from None


class _ConstantParser(ExpressionParser):
    """Parses constant fields: names that are not constants (states, controls, t) get a precise message."""

    def __init__(self, namespace, lines):
        super().__init__(namespace, lines, "a constant field may use numbers, pi, inf, parameters and "
                         "parameter-only definitions", allow_inf=True)
        self.used = set()

    used: set[str]

    def _name(self, node):
        self.used.add(node.id)
        if node.id == "t":
            raise self.error("the time `t` is not a constant; it can be used in dynamics and costs only",
                             self._at(node))
        if node.id in self.namespace and self.namespace[node.id] is None:
            raise self.error(f"`{node.id}` is not a constant; bounds, initial and final values, horizon and guesses "
                             "may use only numbers, pi, inf, parameters and parameter-only definitions", self._at(node))
        return super()._name(node)


def _constant(parser: ExpressionParser, e: Expr, finite: bool) -> float:
    value = parser.parse(e)
    if value.free_symbols:
        raise parser.error(f"`{e.text}` is not a constant", e.loc)
    if value in (sympy.oo, -sympy.oo):
        if finite:
            raise parser.error("must be finite here (infinite values are only allowed in bounds)", e.loc)
        return math.inf if value == sympy.oo else -math.inf
    try:
        number = complex(value.evalf(30))
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        raise parser.error(f"`{e.text}` does not evaluate to a number", e.loc) from None
    if number.imag != 0 or math.isnan(number.real):
        raise parser.error(f"`{e.text}` does not evaluate to a real number", e.loc)
    if math.isinf(number.real) and finite:
        raise parser.error("must be finite here (infinite values are only allowed in bounds)", e.loc)
    return float(number.real)
