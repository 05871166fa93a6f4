"""A strict subclass of sympy's ``JaxPrinter``: an explicit whitelist of printable nodes, nothing printed wrong.

Anything the table does not cover raises :class:`CodegenError` naming the node and the spec field being printed,
instead of sympy's default of emitting a "Not supported" comment or a partially printed expression.
"""

from __future__ import annotations

from typing import ClassVar

import sympy
from sympy.printing.numpy import JaxPrinter

from .errors import CodegenError
from .expressions import wrap_floor, wrap_mod

__all__ = ["StrictJaxPrinter"]

# Function heads that print as jax.numpy.<name>(args...).
_ELEMENTWISE = {
    sympy.exp: "exp", sympy.log: "log", sympy.sin: "sin", sympy.cos: "cos", sympy.tan: "tan",
    sympy.asin: "arcsin", sympy.acos: "arccos", sympy.atan: "arctan", sympy.sinh: "sinh", sympy.cosh: "cosh",
    sympy.tanh: "tanh", sympy.Abs: "abs", sympy.sign: "sign", sympy.atan2: "arctan2", sympy.floor: "floor",
    wrap_floor: "floor", wrap_mod: "mod",
}
_REL = {"<": "less", "<=": "less_equal", ">": "greater", ">=": "greater_equal", "==": "equal", "!=": "not_equal"}


class StrictJaxPrinter(JaxPrinter):
    """Prints the whitelisted sympy subset as ``jax.numpy`` calls.

    Args:
        field: the spec field being printed, for error messages (set with :meth:`for_field`).
    """

    _default_settings: ClassVar[dict] = {
        **JaxPrinter._default_settings, "strict": True, "fully_qualified_modules": True,
    }

    def __init__(self, settings=None):
        super().__init__(settings or {})
        self.field = "<expression>"

    def for_field(self, field: str) -> StrictJaxPrinter:
        self.field = field
        return self

    def _jnp(self, name: str) -> str:
        return self._module_format("jax.numpy." + name)

    def _unsupported(self, expr) -> str:
        err = CodegenError(f"cannot print `{type(expr).__name__}` (in {self.field}: {str(expr)[:80]}); "
                           "myriadc supports the functions listed in specs/README.md")
        err.field = self.field
        raise err

    # Anything not explicitly handled below is an error, not a comment in the output.
    _print_not_supported = _unsupported
    emptyPrinter = _unsupported

    def _print_Function(self, expr):
        name = _ELEMENTWISE.get(expr.func)
        if name is None:
            return self._unsupported(expr)
        return "{}({})".format(self._jnp(name), ", ".join(self._print(a) for a in expr.args))

    _print_exp = _print_log = _print_sin = _print_cos = _print_tan = _print_asin = _print_acos = _print_Function
    _print_atan = _print_sinh = _print_cosh = _print_tanh = _print_Abs = _print_sign = _print_Function
    _print_atan2 = _print_floor = _print_wrap_floor = _print_wrap_mod = _print_Function

    def _print_Heaviside(self, expr):
        # d/dx max(x, y) and friends; H(0) = 1/2 matches sympy's default.
        return "{}({}, 0.5)".format(self._jnp("heaviside"), self._print(expr.args[0]))

    def _print_Min(self, expr):
        return self._fold("minimum", expr.args)

    def _print_Max(self, expr):
        return self._fold("maximum", expr.args)

    def _fold(self, fn, args):
        args = sorted(args, key=sympy.default_sort_key)
        out = self._print(args[0])
        for a in args[1:]:
            out = f"{self._jnp(fn)}({out}, {self._print(a)})"
        return out

    def _print_Piecewise(self, expr):
        if expr.args[-1].cond is not sympy.true:
            # The spec grammar always supplies a default; derived expressions keep it.
            raise CodegenError(f"piecewise expression without a default (in {self.field})")
        out = self._print(expr.args[-1].expr)
        for piece in reversed(expr.args[:-1]):
            out = "{}({}, {}, {})".format(self._jnp("where"), self._print(piece.cond), self._print(piece.expr), out)
        return out

    def _print_Relational(self, expr):
        op = _REL.get(expr.rel_op)
        if op is None:
            return self._unsupported(expr)
        return f"{self._jnp(op)}({self._print(expr.lhs)}, {self._print(expr.rhs)})"

    def _print_And(self, expr):
        return self._fold("logical_and", expr.args)

    def _print_Or(self, expr):
        return self._fold("logical_or", expr.args)

    def _print_Not(self, expr):
        return "{}({})".format(self._jnp("logical_not"), self._print(expr.args[0]))

    def _print_BooleanTrue(self, expr):
        return "True"

    def _print_BooleanFalse(self, expr):
        return "False"

    def _print_Integer(self, expr):
        # Python ints beyond int64 would overflow when JAX converts them; large magnitudes print as floats.
        if abs(int(expr)) >= 2**53:
            return repr(float(expr))
        return str(int(expr))

    def _print_Rational(self, expr):
        if abs(expr.p) >= 2**53 or abs(expr.q) >= 2**53:
            return repr(float(expr))
        return f"{expr.p}/{expr.q}"

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Pow(self, expr, rational=False):
        base, exp = expr.as_base_exp()
        if exp.is_Integer and exp < 0:
            # sympy would print x**(-2.0); keep integer powers integer (exact, and a cheap multiply in XLA).
            inner = base if exp == -1 else sympy.Pow(base, -exp, evaluate=False)
            return "1/{}".format(self.parenthesize(inner, sympy.printing.precedence.PRECEDENCE["Pow"]))
        if exp == sympy.Rational(1, 2):
            return "{}({})".format(self._jnp("sqrt"), self._print(base))
        if exp == -sympy.Rational(1, 2):
            return "1/{}({})".format(self._jnp("sqrt"), self._print(base))
        return super()._print_Pow(expr, rational=rational)

    def _print_Infinity(self, expr):
        return self._jnp("inf")

    def _print_NegativeInfinity(self, expr):
        return "-" + self._jnp("inf")

    def _print_ComplexInfinity(self, expr):
        return self._unsupported(expr)

    def _print_NaN(self, expr):
        return self._unsupported(expr)

    def _print_ImaginaryUnit(self, expr):
        return self._unsupported(expr)

    def _print_Derivative(self, expr):
        return self._unsupported(expr)

    def _print_Subs(self, expr):
        return self._unsupported(expr)
