"""The expression grammar: one spec expression (text) → sympy, through a whitelist, never through ``eval``.

Spec text is never handed to ``eval``, ``exec`` or ``sympy.sympify``/``parse_expr`` (which evaluate Python). It is
parsed by :func:`ast.parse` (which only builds a tree) and the tree is walked here: every node type, function and
name must be on a whitelist, or the walk stops with a :class:`SpecError` that points at the offending column. Decimal
literals become exact rationals. ``mod`` is :class:`wrap_mod` (with :class:`wrap_floor`), sympy functions with the
almost-everywhere derivatives sympy's own lack, which the JAX printer and the CasADi export print. Which names an
expression may use is the caller's namespace: the symbolic pass (:mod:`.symbolic`) decides it.
"""

from __future__ import annotations

import ast
import difflib
import fractions
import math

import sympy

from .errors import Location, SpecError, Unresolved
from .schema import Expr

__all__ = ["CONSTANTS", "FAILED", "FUNCTIONS", "ExpressionParser", "wrap_floor", "wrap_mod"]

# A namespace entry whose own expression failed (its error is recorded): a use of it raises Unresolved, so one
# mistake is reported once, not again at every field that uses the name.
FAILED = object()

MAX_EXPR_CHARS = 10_000
MAX_DEPTH = 200
MAX_NUMBER_BITS = 4096  # exact numbers beyond this (~1200 digits) are far outside float64 and too long to print


class wrap_mod(sympy.Function):  # lower-case, as sympy names its functions
    """x modulo m with the sign of m (like numpy.mod), with the almost-everywhere derivatives sympy's Mod lacks."""

    nargs = 2

    @classmethod
    def eval(cls, x, m):
        if x.is_Number and m.is_Number and m != 0:
            return sympy.Mod(x, m)
        return None

    def fdiff(self, argindex=1):
        x, m = self.args
        if argindex == 1:
            return sympy.Integer(1)
        return -wrap_floor(x / m)

    def _eval_evalf(self, prec):
        x, m = (a.evalf(prec) for a in self.args)
        if x.is_Number and m.is_Number and m != 0:  # like eval: x mod 0 stays unevaluated
            return sympy.Mod(x, m).evalf(prec)
        return None


class wrap_floor(sympy.Function):
    """floor with derivative 0 (almost everywhere); sympy's floor has none, and an unevaluated one cannot print."""

    nargs = 1

    @classmethod
    def eval(cls, x):
        return sympy.floor(x) if x.is_Number else None

    def fdiff(self, argindex=1):
        return sympy.Integer(0)

    def _eval_evalf(self, prec):
        x = self.args[0].evalf(prec)
        return sympy.floor(x) if x.is_Number else None


def _clip(x, lo, hi):
    return sympy.Min(sympy.Max(x, lo), hi)


# name: (sympy constructor, min args, max args or None for variadic)
FUNCTIONS = {
    "exp": (sympy.exp, 1, 1),
    "log": (sympy.log, 1, 1),
    "sqrt": (sympy.sqrt, 1, 1),
    "sin": (sympy.sin, 1, 1),
    "cos": (sympy.cos, 1, 1),
    "tan": (sympy.tan, 1, 1),
    "asin": (sympy.asin, 1, 1),
    "acos": (sympy.acos, 1, 1),
    "atan": (sympy.atan, 1, 1),
    "sinh": (sympy.sinh, 1, 1),
    "cosh": (sympy.cosh, 1, 1),
    "tanh": (sympy.tanh, 1, 1),
    "abs": (sympy.Abs, 1, 1),
    "sign": (sympy.sign, 1, 1),
    "atan2": (sympy.atan2, 2, 2),
    "min": (sympy.Min, 2, None),
    "max": (sympy.Max, 2, None),
    "clip": (_clip, 3, 3),
    "mod": (wrap_mod, 2, 2),
    "where": (None, 3, 3),
    "piecewise": (None, 3, None),
}
CONSTANTS = {"pi": sympy.pi}

_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_BAD_BINOPS = {
    ast.BitXor: "`^` is not a power here; write `x**2` for x squared",
    ast.Mod: "`%` is not supported; write `mod(x, m)`",
    ast.FloorDiv: "`//` is not supported; write `x/y` (or `mod`)",
    ast.MatMult: "`@` is not supported",
    ast.LShift: "`<<` is not supported", ast.RShift: "`>>` is not supported",
    ast.BitAnd: "`&` is not supported; in a condition write `and`",
    ast.BitOr: "`|` is not supported; in a condition write `or`",
}
_COMPARE = {
    ast.Lt: sympy.Lt, ast.LtE: sympy.Le, ast.Gt: sympy.Gt, ast.GtE: sympy.Ge, ast.Eq: sympy.Eq, ast.NotEq: sympy.Ne,
}
_NODE_NAMES = {
    ast.Attribute: "attribute access (`a.b`)", ast.Subscript: "indexing (`a[i]`)", ast.Lambda: "a lambda",
    ast.IfExp: "`a if c else b` (write `where(c, a, b)`)", ast.List: "a list", ast.Tuple: "a tuple",
    ast.Dict: "a dict", ast.Set: "a set", ast.ListComp: "a comprehension", ast.GeneratorExp: "a generator",
    ast.DictComp: "a comprehension", ast.SetComp: "a comprehension", ast.Starred: "`*` unpacking",
    ast.NamedExpr: "`:=`", ast.JoinedStr: "an f-string", ast.Await: "`await`", ast.Yield: "`yield`",
}


class ExpressionParser:
    """Turns one spec expression into sympy, resolving names against an explicit namespace.

    Args:
        namespace: name -> sympy expression (a Symbol, or a definition's expression to inline).
        hint: what to say when a name is undeclared.
        allow_inf: accept `inf` (numeric constant fields such as bounds).
    """

    def __init__(self, namespace: dict, lines: tuple[str, ...], hint: str, allow_inf: bool = False):
        self.namespace = namespace
        self.lines = lines
        self.hint = hint
        self.allow_inf = allow_inf

    def error(self, message: str, loc: Location) -> SpecError:
        line = self.lines[loc.line - 1] if 0 < loc.line <= len(self.lines) else None
        return SpecError(message, loc, line)

    def parse(self, expr: Expr):
        value = self._parse(expr)
        if any(max(abs(n.p), n.q).bit_length() > MAX_NUMBER_BITS for n in value.atoms(sympy.Rational)):
            raise self.error(f"a number here is too large (more than {MAX_NUMBER_BITS} bits); float64 code cannot "
                             "use it: rescale the problem", expr.loc)
        return value

    def _parse(self, expr: Expr):
        if expr.number is not None:
            return _number_from_text(expr.text, expr.number)
        text = expr.text
        if not text.strip():
            raise self.error("empty expression; write a number or a formula", expr.loc)
        if len(text) > MAX_EXPR_CHARS:
            raise self.error(f"expression longer than {MAX_EXPR_CHARS} characters; use `definitions:` to split it",
                             expr.loc)
        if "\x00" in text:
            raise self.error("expression contains a NUL character", expr.loc)
        try:
            tree = ast.parse(text.strip() if not expr.offset_ok else text, mode="eval")
        except SyntaxError as exc:
            col = (exc.offset or 1) - 1 if exc.lineno in (None, 1) else 0
            msg = exc.msg.split(" (")[0]
            if exc.lineno in (None, 1) and exc.offset == 0:  # Python reports the end of the input as offset 0
                col, msg = len(text.rstrip()), "unexpected end of expression"
            raise self.error(f"syntax error in expression: {msg}; expressions use + - * / ** and f(x)",
                             expr.at(col)) from None
        except (RecursionError, MemoryError, ValueError) as exc:
            raise self.error(f"cannot parse expression ({type(exc).__name__}); simplify it", expr.loc) from None
        self._expr = expr
        self._text = text
        try:
            return self._value(tree.body, 0)
        except RecursionError:
            raise self.error("expression nested too deeply; use `definitions:` to split it", expr.loc) from None

    # -- helpers -------------------------------------------------------------------------------------------
    def _at(self, node: ast.AST) -> Location:
        return self._expr.at(getattr(node, "col_offset", 0)) if getattr(node, "lineno", 1) == 1 else self._expr.loc

    def _segment(self, node: ast.AST) -> str:
        seg = ast.get_source_segment(self._text, node) or ""
        return seg if len(seg) <= 40 else seg[:37] + "..."

    def _reject(self, node: ast.AST):
        what = _NODE_NAMES.get(type(node), f"`{type(node).__name__}`")
        raise self.error(f"{what} is not allowed in expressions; use numbers, declared names, + - * / ** and the "
                         "functions listed in specs/README.md", self._at(node))

    def _check_depth(self, node, depth):
        if depth > MAX_DEPTH:
            raise self.error("expression nested too deeply; use `definitions:` to split it", self._at(node))

    # -- values ----------------------------------------------------------------------------------------------
    def _value(self, node: ast.AST, depth: int):
        self._check_depth(node, depth)
        if isinstance(node, ast.Constant):
            v = node.value
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                kind = "text" if isinstance(v, str) else type(v).__name__
                raise self.error(f"{kind} `{self._segment(node)}` is not a number; expressions take numbers and "
                                 "declared names only", self._at(node))
            return _number_from_text(self._segment(node) or repr(v), v)
        if isinstance(node, ast.Name):
            return self._name(node)
        if isinstance(node, ast.BinOp):
            op = type(node.op)
            if op in _BAD_BINOPS:
                raise self.error(_BAD_BINOPS[op], self._at(node))
            a = self._value(node.left, depth + 1)
            b = self._value(node.right, depth + 1)
            if op is ast.Add:
                return a + b
            if op is ast.Sub:
                return a - b
            if op is ast.Mult:
                return a * b
            if op is ast.Div:
                if b == 0:
                    raise self.error("division by zero", self._at(node))
                return a / b
            if a.is_Rational and b.is_Rational and max(abs(a.p), a.q) > 1 and \
                    max(abs(a.p), a.q).bit_length() * abs(b) > MAX_NUMBER_BITS:  # before sympy computes it exactly
                raise self.error(f"`{self._segment(node)}` is too large a number (more than {MAX_NUMBER_BITS} bits); "
                                 "float64 code cannot use it: rescale the problem", self._at(node))
            return sympy.Pow(a, b)
        if isinstance(node, ast.UnaryOp):
            if isinstance(node.op, ast.USub):
                return -self._value(node.operand, depth + 1)
            if isinstance(node.op, ast.UAdd):
                return self._value(node.operand, depth + 1)
            if isinstance(node.op, ast.Not):
                raise self.error("`not` is only allowed in the condition of where()/piecewise()", self._at(node))
            raise self.error("`~` is not supported", self._at(node))
        if isinstance(node, ast.Call):
            return self._call(node, depth)
        if isinstance(node, (ast.Compare, ast.BoolOp)):
            raise self.error("a comparison is only allowed as the condition of where(cond, a, b) or piecewise()",
                             self._at(node))
        self._reject(node)

    def _name(self, node: ast.Name):
        name = node.id
        if name in self.namespace:
            if self.namespace[name] is FAILED:
                raise Unresolved(name)
            return self.namespace[name]
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name == "inf" and self.allow_inf:
            return sympy.oo
        if name.startswith("_"):
            raise self.error(f"names starting with `_` are not allowed (`{name}`)", self._at(node))
        if name in FUNCTIONS:
            raise self.error(f"`{name}` is a function; call it as `{name}(...)`", self._at(node))
        if name == "inf":
            raise self.error("`inf` is only allowed in bounds", self._at(node))
        if name == "e":
            raise self.error("`e` is not a constant here; write `exp(1)`", self._at(node))
        close = difflib.get_close_matches(name, [*self.namespace, *CONSTANTS], n=1)
        suggestion = f" (did you mean `{close[0]}`?)" if close else ""
        raise self.error(f"undeclared symbol `{name}`{suggestion}; {self.hint}", self._at(node))

    def _call(self, node: ast.Call, depth: int):
        if not isinstance(node.func, ast.Name):
            raise self.error("only the listed functions can be called, by name (e.g. `exp(x)`); attribute or "
                             "computed calls are not allowed", self._at(node))
        fname = node.func.id
        if fname not in FUNCTIONS:
            close = difflib.get_close_matches(fname, FUNCTIONS, n=1)
            suggestion = f" (did you mean `{close[0]}`?)" if close else ""
            raise self.error(f"unknown function `{fname}`{suggestion}; allowed: {', '.join(FUNCTIONS)}",
                             self._at(node))
        if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
            raise self.error(f"`{fname}` takes positional arguments only", self._at(node))
        ctor, lo, hi = FUNCTIONS[fname]
        n = len(node.args)
        if n < lo or (hi is not None and n > hi):
            want = f"{lo}" if lo == hi else (f"{lo} or more" if hi is None else f"{lo} to {hi}")
            raise self.error(f"`{fname}` takes {want} arguments, got {n}", self._at(node))
        if fname == "where":
            cond = self._condition(node.args[0], depth + 1)
            a = self._value(node.args[1], depth + 1)
            b = self._value(node.args[2], depth + 1)
            return sympy.Piecewise((a, cond), (b, True))
        if fname == "piecewise":
            if n % 2 == 0:
                raise self.error("`piecewise(c1, a1, ..., default)` needs a default value as its last argument "
                                 f"(got {n} arguments, an even number)", self._at(node))
            pieces = []
            for i in range(0, n - 1, 2):
                pieces.append((self._value(node.args[i + 1], depth + 1), self._condition(node.args[i], depth + 1)))
            pieces.append((self._value(node.args[-1], depth + 1), True))
            return sympy.Piecewise(*pieces)
        args = [self._value(a, depth + 1) for a in node.args]
        if fname == "mod" and args[1] == 0:
            raise self.error("division by zero: `mod(x, 0)`", self._at(node))
        return self._apply(node, f"`{fname}`", ctor, *args)

    def _apply(self, node: ast.AST, what: str, fn, *args):
        """sympy refuses some constant arguments (complex, nan) with TypeError/ValueError: report them at the call."""
        try:
            return fn(*args)
        except (TypeError, ValueError) as exc:
            why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise self.error(f"{what} cannot be evaluated here ({why}); its arguments must be real and defined "
                             "(check for complex results such as log(-1) or acos(2), and for inf - inf)",
                             self._at(node)) from None

    # -- conditions ------------------------------------------------------------------------------------------
    def _condition(self, node: ast.AST, depth: int):
        self._check_depth(node, depth)
        if isinstance(node, ast.Compare):
            terms = [self._value(node.left, depth + 1)] + [self._value(c, depth + 1) for c in node.comparators]
            parts = []
            for op, a, b in zip(node.ops, terms, terms[1:]):
                rel = _COMPARE.get(type(op))
                if rel is None:
                    raise self.error("only < <= > >= == != comparisons are allowed", self._at(node))
                parts.append(self._apply(node, "the comparison", rel, a, b))
            return sympy.And(*parts)
        if isinstance(node, ast.BoolOp):
            parts = [self._condition(v, depth + 1) for v in node.values]
            return sympy.And(*parts) if isinstance(node.op, ast.And) else sympy.Or(*parts)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return sympy.Not(self._condition(node.operand, depth + 1))
        raise self.error("a condition must be a comparison such as `x > 0` (joined with and/or/not)", self._at(node))


def _number_from_text(text: str, value) -> sympy.Expr:
    """An exact sympy number for a literal: decimals become rationals so no binary rounding enters the IR."""
    if isinstance(value, float) and math.isnan(value):
        return sympy.nan
    if isinstance(value, float) and not math.isfinite(value):
        return sympy.oo if value > 0 else -sympy.oo
    if isinstance(value, int) and not isinstance(value, bool):
        return sympy.Integer(value)
    digits = text.strip().replace("_", "")
    exponent = digits.lower().rpartition("e")[2].lstrip("+-").lstrip("0")
    try:
        if len(digits) > 400 or ("e" in digits.lower() and len(exponent) > 3):
            raise ValueError  # the exact value would need a huge integer; the float is what the code can hold
        frac = fractions.Fraction(digits)
    except (ValueError, ZeroDivisionError):
        frac = fractions.Fraction(value)
    return sympy.Rational(frac.numerator, frac.denominator)
