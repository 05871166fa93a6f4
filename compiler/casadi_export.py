"""Export a compiled spec to CasADi: f, L and phi (minimisation form) as ``casadi.Function`` objects.

    from myriad.compiler.build import check_file
    from myriad.compiler.casadi_export import to_casadi

    cs = to_casadi(check_file("specs/pendulum.yaml"))   # or compile_file(path).symbolic; or export_file(path)
    cs.f(x, u, t, cs.p0)                                 # casadi DM; also cs.L(x, u, t, p), cs.phi(x, t, p)
    cs.g(x, u, t, cs.p0)                                 # path constraints (schema 2): cs.path_lower <= g <= ...

A schema 2 spec also carries its free final time (``free_horizon``, ``horizon_bounds``; ``horizon`` is then the
guess); :mod:`.casadi_opti` poses the whole problem with ``casadi.Opti`` (path constraints at every node, T a
variable).

A schema 3 spec carries its uncertainty as data, with the names and meanings of the generated system's attributes
(specs/README.md): ``uncertain_params``, ``uncertain_kinds``, ``uncertain_args``, ``scenarios`` (rows of values of the
uncertain parameters), ``robust_objective``/``robust_alpha``/``robust_samples``/``robust_seed``, ``process_noise`` and
``observation_noise``. ``cs.scenario_params()`` turns the scenarios into ``p`` vectors, so the scenario problem is one
loop away (one control trajectory, each scenario its own states)::

    costs = []
    for p in cs.scenario_params():            # the explicit scenarios; or scenario_params(rows) for drawn ones
        X = opti.variable(cs.n_states, N + 1)  # ... its dynamics, bounds and cost J_s with cs.f, cs.L, cs.phi at p
        costs.append(J_s)
    opti.minimize(sum(costs) / len(costs))    # robust_objective "mean"

:func:`.casadi_opti.scenario_trapezoidal` is that problem written out (mean, worst case, CVaR).

This is an independent peer of the generated JAX code (bench/casadi_peer.py solves the same discretised problems
with CasADi + IPOPT; tests/compiler/test_casadi_export.py checks that both agree). It starts from the compiler's
checked :class:`~myriad.compiler.schema.SymbolicProblem` and :func:`~myriad.compiler.optimal_control.derive` (so a
``maximize`` spec is negated exactly as for JAX), and never sees spec text: every sympy expression is walked node by
node against an explicit whitelist (:data:`SUPPORTED`), and any other node raises :class:`CasadiExportError` naming
it and the field it came from.

casadi is an optional dependency (``pip install myriad[bench]``): it is imported inside the functions here, never at
module import, so ``import myriad.compiler`` neither needs nor loads it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator
import os
from collections.abc import Mapping
from typing import Any

import sympy

from .errors import CodegenError
from .expressions import wrap_floor, wrap_mod
from .lower import schema3_attributes
from .optimal_control import derive
from .schema import SymbolicProblem

__all__ = ["SUPPORTED", "CasadiExportError", "CasadiSystem", "export_file", "sympy_to_casadi", "to_casadi"]

# What the walk accepts, for messages and documentation (the dispatch itself is in _Converter).
SUPPORTED = (
    "numbers (Integer, Rational, Float, pi, E, +-oo), symbols, Add, Mul, Pow, exp, log, sin, cos, tan, asin, "
    "acos, atan, sinh, cosh, tanh, Abs, sign, atan2, Min, Max, Piecewise, relationals (< <= > >= == !=), And, Or, "
    "Not, true/false, wrap_mod, wrap_floor"
)


class CasadiExportError(CodegenError):
    """An expression uses a sympy node the CasADi export does not translate (or a symbol the function lacks)."""


@dataclasses.dataclass(frozen=True)
class CasadiSystem:
    """One spec as CasADi functions plus the metadata to pose its optimal-control problem.

    Functions (all in minimisation form, like the generated JAX system):
        f(x, u, t, p) -> (n_states,) state derivative;
        L(x, u, t, p) -> scalar running cost;
        phi(x, t, p) -> scalar terminal cost (t is the final time T);
        g(x, u, t, p) -> (n_path,) path constraints, path_lower <= g <= path_upper along the trajectory (schema 2).
    ``x`` is (n_states,), ``u`` (n_controls,), ``t`` a scalar and ``p`` (n_params,) the parameter values in
    ``param_names`` order (``p0`` holds the spec's values). Infinite bounds are ``+-math.inf``; ``x_final`` is None
    where the final state is free.
    """

    name: str
    sense: str
    f: Any
    L: Any
    phi: Any
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    param_names: tuple[str, ...]
    param_values: tuple[float, ...]
    x0: tuple[float, ...]
    x_lower: tuple[float, ...]
    x_upper: tuple[float, ...]
    u_lower: tuple[float, ...]
    u_upper: tuple[float, ...]
    x_final: tuple[float | None, ...]
    horizon: float  # the fixed final time, or the guess of a free one
    g: Any = None
    path_names: tuple[str, ...] = ()
    path_lower: tuple[float, ...] = ()
    path_upper: tuple[float, ...] = ()
    horizon_bounds: tuple[float, float] | None = None  # a free final time's bounds, else None
    # Schema 3 (empty or None otherwise), as the generated system's attributes of the same names.
    uncertain_params: tuple[str, ...] = ()
    uncertain_kinds: tuple[str, ...] = ()
    uncertain_args: tuple[tuple[float, ...], ...] = ()
    scenarios: tuple[tuple[float, ...], ...] = ()
    robust_objective: str | None = None
    robust_alpha: float | None = None
    robust_samples: int = 16
    robust_seed: int = 0
    process_noise: tuple[float, ...] = ()
    observation_noise: tuple[float, ...] = ()

    @property
    def free_horizon(self) -> bool:
        return self.horizon_bounds is not None

    @property
    def n_path(self) -> int:
        return len(self.path_names)

    @property
    def n_states(self) -> int:
        return len(self.state_names)

    @property
    def n_controls(self) -> int:
        return len(self.control_names)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def p0(self) -> list[float]:
        """The spec's parameter values as the ``p`` argument."""
        return list(self.param_values)

    def params_vector(self, params: Mapping[str, float] | None = None) -> list[float]:
        """``p`` for a (partial) ``{name: value}`` dict; names not given keep the spec's value."""
        params = dict(params or {})
        unknown = set(params) - set(self.param_names)
        if unknown:
            raise KeyError(f"{self.name}: unknown parameters {sorted(unknown)}; expected some of "
                           f"{list(self.param_names)}")
        return [float(params.get(k, v)) for k, v in zip(self.param_names, self.param_values)]

    def scenario_params(self, rows=None) -> list[list[float]]:
        """One ``p`` vector per scenario: ``rows`` (each the values of ``uncertain_params`` in order; default the
        explicit ``scenarios``) with every other parameter at the spec's value."""
        rows = self.scenarios if rows is None else rows
        out = []
        for row in rows:
            row = [float(v) for v in row]
            if len(row) != len(self.uncertain_params):
                raise ValueError(f"{self.name}: a scenario row holds one value per uncertain parameter "
                                 f"{list(self.uncertain_params)}, got {len(row)}")
            out.append(self.params_vector(dict(zip(self.uncertain_params, row))))
        return out


def _casadi():
    try:
        import casadi
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the CasADi export needs casadi: pip install 'myriad[bench]' (or casadi>=3.6)") from exc
    return casadi


def to_casadi(sym: SymbolicProblem) -> CasadiSystem:
    """The CasADi functions f, L, phi of a checked symbolic problem, in minimisation form.

    Args:
        sym: from :func:`myriad.compiler.build.check_file` or ``compile_file(path).symbolic``.

    Raises:
        CasadiExportError: an expression uses a node outside :data:`SUPPORTED`.
    """
    ca = _casadi()
    d = derive(sym)
    n, m, k = len(sym.states), len(sym.controls), len(sym.params)
    x = ca.SX.sym("x", n)
    u = ca.SX.sym("u", m)
    t = ca.SX.sym("t")
    p = ca.SX.sym("p", k)
    xs = {s: x[i] for i, s in enumerate(sym.states)}
    us = {s: u[i] for i, s in enumerate(sym.controls)}
    ps = {s: p[i] for i, s in enumerate(sym.params)}
    running = {**xs, **us, sym.time: t, **ps}
    terminal = {**xs, sym.time: t, **ps}

    f_expr = ca.vertcat(*(sympy_to_casadi(e, running, field=f"dynamics.{s}") for e, s in zip(d.f, sym.states))) \
        if n else ca.SX(0, 1)
    L_expr = sympy_to_casadi(d.L, running, field="cost.running")
    phi_expr = sympy_to_casadi(d.phi, terminal, field="cost.terminal")
    g_expr = ca.vertcat(*(sympy_to_casadi(e, running, field=f"path_constraints.{c.name}")
                          for e, c in zip(sym.path, sym.spec.path_constraints))) if sym.path else ca.SX(0, 1)
    spec = sym.spec
    return CasadiSystem(
        name=spec.name,
        sense=spec.sense,
        f=ca.Function("f", [x, u, t, p], [f_expr], ["x", "u", "t", "p"], ["xdot"]),
        L=ca.Function("L", [x, u, t, p], [L_expr], ["x", "u", "t", "p"], ["L"]),
        phi=ca.Function("phi", [x, t, p], [phi_expr], ["x", "t", "p"], ["phi"]),
        state_names=tuple(s.name for s in spec.states),
        control_names=tuple(c.name for c in spec.controls),
        param_names=tuple(q.name for q in spec.parameters),
        param_values=tuple(float(v) for v in sym.param_values),
        x0=tuple(float(v) for v in sym.x0),
        x_lower=tuple(float(v) for v in sym.x_lower),
        x_upper=tuple(float(v) for v in sym.x_upper),
        u_lower=tuple(float(v) for v in sym.u_lower),
        u_upper=tuple(float(v) for v in sym.u_upper),
        x_final=tuple(None if v is None else float(v) for v in sym.x_final),
        horizon=float(sym.horizon),
        g=ca.Function("g", [x, u, t, p], [g_expr], ["x", "u", "t", "p"], ["g"]),
        path_names=tuple(c.name for c in spec.path_constraints),
        path_lower=tuple(float(v) for v in sym.path_lower),
        path_upper=tuple(float(v) for v in sym.path_upper),
        horizon_bounds=None if sym.horizon_bounds is None else tuple(float(v) for v in sym.horizon_bounds),
        **_uncertainty(sym),
    )


def _uncertainty(sym: SymbolicProblem) -> dict:
    """The schema 3 fields as keyword arguments: the very values the generated module's attributes get."""
    return dict(schema3_attributes(sym))


def export_file(path: str | os.PathLike) -> CasadiSystem:
    """Parse and check a spec file (no JAX code is generated) and export it: ``to_casadi(check_file(path))``."""
    from .build import check_file

    return to_casadi(check_file(path))


def sympy_to_casadi(expr, symbols: Mapping[Any, Any], *, field: str = "<expression>"):
    """Translate one sympy expression into CasADi SX.

    Args:
        expr: a sympy expression (or a boolean condition).
        symbols: sympy Symbol -> CasADi SX scalar for every symbol the expression may use.
        field: where the expression came from, for error messages.

    Raises:
        CasadiExportError: a node outside :data:`SUPPORTED`, or a symbol missing from ``symbols``.
    """
    if isinstance(expr, bool):  # plain Python constants, never text
        expr = sympy.true if expr else sympy.false
    elif isinstance(expr, int):
        expr = sympy.Integer(expr)
    elif isinstance(expr, float):
        expr = sympy.Float(expr)
    elif not isinstance(expr, sympy.Basic):
        raise TypeError(f"sympy_to_casadi takes a sympy expression, not {type(expr).__name__}")
    return _Converter(_casadi(), symbols, field).convert(expr)


class _Converter:
    """An explicit-stack post-order walk (no recursion limit on deep trees), memoised on shared subtrees."""

    def __init__(self, ca, symbols: Mapping[Any, Any], field: str):
        self.ca = ca
        self.symbols = symbols
        self.field = field
        self.functions = {
            sympy.exp: ca.exp, sympy.log: ca.log, sympy.sin: ca.sin, sympy.cos: ca.cos, sympy.tan: ca.tan,
            sympy.asin: ca.asin, sympy.acos: ca.acos, sympy.atan: ca.atan, sympy.sinh: ca.sinh,
            sympy.cosh: ca.cosh, sympy.tanh: ca.tanh, sympy.Abs: ca.fabs, sympy.sign: ca.sign,
            sympy.atan2: ca.atan2, wrap_floor: ca.floor, wrap_mod: self._mod,
        }
        self.relations = {"<": ca.lt, "<=": ca.le, ">": ca.gt, ">=": ca.ge, "==": ca.eq, "!=": ca.ne}

    def error(self, node, why: str = "") -> CasadiExportError:
        text = str(node)
        text = text if len(text) <= 80 else text[:77] + "..."
        why = why or f"the CasADi export supports only {SUPPORTED}"
        err = CasadiExportError(f"cannot export `{type(node).__name__}` to CasADi (in {self.field}: {text}); {why}")
        err.field = self.field
        return err

    def convert(self, root):
        memo: dict = {}
        stack = [(root, False)]
        while stack:
            node, ready = stack.pop()
            if node in memo:
                continue
            if ready:
                memo[node] = self._build(node, [memo[a] for a in node.args])
                continue
            leaf = self._leaf(node)
            if leaf is not None:
                memo[node] = leaf
                continue
            self._check(node)
            stack.append((node, True))
            stack.extend((a, False) for a in reversed(node.args) if a not in memo)
        return memo[root]

    # -- leaves: numbers, symbols, booleans ---------------------------------------------------------------------
    def _leaf(self, node):
        if isinstance(node, sympy.Symbol):
            if node not in self.symbols:
                raise self.error(node, f"the symbol `{node}` is not an argument of this function")
            return self.symbols[node]
        if node is sympy.true:
            return self.ca.SX(1)
        if node is sympy.false:
            return self.ca.SX(0)
        if isinstance(node, (sympy.Integer, sympy.Rational, sympy.Float)):
            return self.ca.SX(float(node))
        if node is sympy.pi or node is sympy.E:
            return self.ca.SX(float(node))
        if node is sympy.oo or node is sympy.S.NegativeInfinity:
            return self.ca.SX(math.inf if node is sympy.oo else -math.inf)
        if isinstance(node, sympy.Basic) and not node.args:
            raise self.error(node)  # nan, zoo, I, other constants: never a silent value
        return None

    # -- interior nodes: whitelist first (before walking any argument), then build --------------------------------
    def _check(self, node):
        if isinstance(node, (sympy.Add, sympy.Mul, sympy.Pow, sympy.Min, sympy.Max, sympy.And, sympy.Or,
                             sympy.Not, sympy.Piecewise, sympy.functions.elementary.piecewise.ExprCondPair)):
            if isinstance(node, sympy.Piecewise) and node.args[-1].cond is not sympy.true:
                raise self.error(node, "a piecewise expression needs a default (a last condition that is True)")
            return
        if isinstance(node, sympy.core.relational.Relational):
            if node.rel_op not in self.relations:
                raise self.error(node)
            return
        if isinstance(node, sympy.Function) and node.func in self.functions:
            return
        raise self.error(node)

    def _build(self, node, args):
        ca = self.ca
        if isinstance(node, sympy.Add):
            return functools.reduce(operator.add, args)
        if isinstance(node, sympy.Mul):
            return functools.reduce(operator.mul, args)
        if isinstance(node, sympy.Pow):
            return self._pow(node, *args)
        if isinstance(node, (sympy.Min, sympy.Max)):
            return functools.reduce(ca.fmin if isinstance(node, sympy.Min) else ca.fmax, args)
        if isinstance(node, sympy.functions.elementary.piecewise.ExprCondPair):
            return tuple(args)  # (value, condition), consumed by the Piecewise above it
        if isinstance(node, sympy.Piecewise):
            out = args[-1][0]  # the default
            for value, cond in reversed(args[:-1]):
                out = ca.if_else(cond, value, out)
            return out
        if isinstance(node, sympy.core.relational.Relational):
            return self.relations[node.rel_op](*args)
        if isinstance(node, (sympy.And, sympy.Or)):
            return functools.reduce(ca.logic_and if isinstance(node, sympy.And) else ca.logic_or, args)
        if isinstance(node, sympy.Not):
            return ca.logic_not(args[0])
        fn = self.functions[node.func]
        try:
            return fn(*args)
        except (TypeError, NotImplementedError, RuntimeError) as exc:  # wrong arity and the like
            raise self.error(node, f"CasADi refused its arguments ({exc})") from None

    def _pow(self, node, base, exponent):
        ca = self.ca
        e = node.exp
        if e.is_Integer and e < 0:  # as the JAX printer: 1/x**k, keeping integer powers integer
            return 1 / (base if e == -1 else ca.constpow(base, float(-e)))
        if e == sympy.Rational(1, 2):
            return ca.sqrt(base)
        if e == -sympy.Rational(1, 2):
            return 1 / ca.sqrt(base)
        if e.is_Number:
            return ca.constpow(base, float(e))
        return ca.power(base, exponent)

    def _mod(self, x, m):
        """x mod m with the sign of m, exactly as jax.numpy.mod: fmod, moved by m where the signs differ."""
        ca = self.ca
        r = ca.fmod(x, m)
        shift = ca.logic_and(ca.ne(ca.lt(r, 0), ca.lt(m, 0)), ca.ne(r, 0))
        return ca.if_else(shift, r + m, r)
