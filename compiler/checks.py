"""Pass 3, checks: well-posedness before any code is generated.

``check_names`` runs on the parsed spec (names decide how expressions resolve, so it comes before the symbolic pass);
``check_problem`` runs on the symbolic problem (equations per state, bounds, conditions, what costs may depend on).
"""

from __future__ import annotations

import builtins
import keyword
import math
import os
import re

import sympy

from .checks_schema3 import check_uncertainty
from .errors import ErrorLog, Location, SpecError
from .expressions import CONSTANTS, FUNCTIONS
from .schema import ProblemSpec, SymbolicProblem

__all__ = ["RESERVED", "check_equations", "check_names", "check_problem"]

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
_SYSTEM_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")
# Names the generated module or its readers use: a spec symbol with one of these names would shadow them.
RESERVED = frozenset({
    "t", "e", "inf", "nan", "jax", "jnp", "np", "numpy", "math", "myriad", "self", "params", "cls", "System",
    "functools", "sympy", "None", "True", "False",
    *FUNCTIONS, *CONSTANTS, *dir(builtins),
})


def _error(spec: ProblemSpec, message: str, loc: Location) -> SpecError:
    line = spec.lines[loc.line - 1] if 0 < loc.line <= len(spec.lines) else None
    return SpecError(message, loc, line)


def _show(name: str) -> str:
    text = "".join(ch if ch.isprintable() else "?" for ch in name)
    return text if len(text) <= 40 else text[:37] + "..."


def check_names(spec: ProblemSpec, log: ErrorLog) -> None:
    """System name, symbol names (identifier, not reserved, unique across sections): every bad name is recorded.

    The symbolic pass resolves expressions by these names, so the pipeline stops after this check when it failed.
    """
    log.attempt(_check_system_name, spec)
    seen: dict[str, str] = {}
    groups = [
        ("parameter", [(p.name, p.loc) for p in spec.parameters]),
        ("definition", [(d.name, d.loc) for d in spec.definitions]),
        ("state", [(s.name, s.loc) for s in spec.states]),
        ("control", [(c.name, c.loc) for c in spec.controls]),
    ]
    for kind, names in groups:
        for name, loc in names:
            log.attempt(_check_symbol_name, spec, kind, name, loc, seen)
            seen.setdefault(name, kind)
    for c in spec.path_constraints:
        if not _IDENT.match(c.name):
            log.add(_error(spec, f"path constraint name `{_show(c.name)}` must be an ASCII identifier (letters, "
                           "digits and `_`, starting with a letter), e.g. `keep_out`", c.loc))


def _check_system_name(spec: ProblemSpec) -> None:
    stem = os.path.splitext(os.path.basename(spec.file))[0]
    if keyword.iskeyword(spec.name):
        raise _error(spec, f"system name `{spec.name}` is a Python keyword; it names the generated module: choose "
                     f"another, e.g. `{spec.name}_system`", spec.name_loc)
    if not _SYSTEM_NAME.match(spec.name) or len(spec.name) > 64:
        raise _error(spec, f"system name `{_show(spec.name)}` must be a lowercase identifier ([a-z][a-z0-9_]*, at "
                     "most 64 characters), e.g. `cancer_treatment`; it names the generated module", spec.name_loc)
    if spec.file.endswith((".yaml", ".yml")) and stem != spec.name:
        raise _error(spec, f"name `{_show(spec.name)}` must equal the file stem `{_show(stem)}`; rename the file or "
                     "the system", spec.name_loc)


def _check_symbol_name(spec: ProblemSpec, kind: str, name: str, loc: Location, seen: dict[str, str]) -> None:
    """One declared symbol: an identifier, no keyword, not reserved, not declared before (``seen``: name → kind)."""
    if not _IDENT.match(name):
        why = "must not start with `_`" if name.startswith("_") else "must be an ASCII identifier"
        raise _error(spec, f"{kind} name `{_show(name)}` {why} (letters, digits and `_`, starting with a "
                     "letter), e.g. `theta_dot`", loc)
    if keyword.iskeyword(name) or keyword.issoftkeyword(name):
        raise _error(spec, f"{kind} name `{name}` is a Python keyword; choose another, e.g. `{name}_`", loc)
    if name in RESERVED:
        raise _error(spec, f"{kind} name `{name}` is reserved (a function, constant or name the generated code "
                     f"uses); choose another, e.g. `{name}_{kind[0]}`", loc)
    if name in seen:
        raise _error(spec, f"{kind} name `{name}` is already declared as a {seen[name]}; states, controls, "
                     "parameters and definitions share one namespace", loc)


def check_equations(spec: ProblemSpec, log: ErrorLog) -> None:
    """One equation per state, and none for anything else: every mismatch is recorded (the symbolic pass does not
    depend on it, so the pipeline goes on)."""
    kinds = {**{c.name: "control" for c in spec.controls}, **{s.name: "state" for s in spec.states}}
    state_names = [s.name for s in spec.states]
    for eq in spec.dynamics:
        if eq.name not in state_names:
            hint = "it is a control: only states have equations" if kinds.get(eq.name) == "control" else \
                f"declared states: {', '.join(state_names)}"
            log.add(_error(spec, f"equation for `{_show(eq.name)}`, which is not a state; {hint}", eq.loc))
    have = {eq.name for eq in spec.dynamics}
    for s in spec.states:
        if s.name not in have:
            log.add(_error(spec, f"state `{s.name}` has no equation; add `{s.name}: <expression>` under `dynamics:`",
                           spec.dynamics_loc))


def check_problem(sym: SymbolicProblem, log: ErrorLog) -> None:
    """Bounds well-formed, initial and final values inside bounds, horizon, and what each cost may use.

    Every check runs on its own and records what it finds; a field the symbolic pass could not build (None in a
    partial problem) is skipped, its error already recorded.
    """
    spec = sym.spec
    for var, lo, hi in [*zip(spec.states, sym.x_lower, sym.x_upper), *zip(spec.controls, sym.u_lower, sym.u_upper)]:
        log.attempt(_check_bounds, spec, var, lo, hi)
    for s, x0, lo, hi, xf in zip(spec.states, sym.x0, sym.x_lower, sym.x_upper, sym.x_final):
        log.attempt(_check_inside, spec, s, x0, lo, hi, xf)
    if sym.free_horizon:
        log.attempt(_check_free_horizon, sym)
    elif sym.horizon is not None and not sym.horizon > 0:
        log.add(_error(spec, f"horizon must be positive, got {sym.horizon:g}", spec.horizon.loc))
    for c, e, lo, hi in zip(spec.path_constraints, sym.path, sym.path_lower, sym.path_upper):
        log.attempt(_check_path_constraint, sym, c, e, lo, hi)
    controls = set(sym.controls)
    used = sym.terminal.free_symbols & controls if sym.terminal is not None else set()
    if used and spec.terminal is not None:
        names = ", ".join(sorted(str(u) for u in used))
        log.add(_error(spec, f"the terminal cost uses the control(s) {names}; it is a function of the final state "
                       "(and parameters) only: move control terms into `running`", spec.terminal.loc))
    equations = {eq.name: eq.expr for eq in spec.dynamics}
    exprs = [("dynamics." + s.name, e, equations[s.name]) for s, e in zip(spec.states, sym.dynamics)
             if s.name in equations]
    exprs.append(("cost.running", sym.running, spec.running))
    if spec.terminal is not None:
        exprs.append(("cost.terminal", sym.terminal, spec.terminal))
    exprs += [(f"path_constraints.{c.name}", e, c.expr) for c, e in zip(spec.path_constraints, sym.path)]
    for field, e, src in exprs:
        if e is not None:
            log.attempt(_check_value, spec, field, e, src)
    check_uncertainty(sym, log)  # schema 3; nothing to check in an earlier schema's spec


def _check_bounds(spec: ProblemSpec, var, lo: float | None, hi: float | None) -> None:
    """A state's or control's bounds: not [+inf, ...] nor [..., -inf], and not reversed."""
    loc = var.bounds_loc or var.loc
    if lo is None or hi is None:
        return
    if lo == math.inf or hi == -math.inf:
        raise _error(spec, f"bounds of `{var.name}` are [{lo}, {hi}]: the lower bound cannot be +inf nor the "
                     "upper -inf; write `[-.inf, .inf]` for unbounded", loc)
    if lo > hi:
        raise _error(spec, f"bounds of `{var.name}` are reversed: lower {lo:g} > upper {hi:g}; write "
                     "`[lower, upper]`", loc)


def _check_inside(spec: ProblemSpec, s, x0: float | None, lo: float | None, hi: float | None,
                  xf: float | None) -> None:
    """A state's initial and required final values inside its bounds (well-formed ones: bad bounds have their own
    error)."""
    if lo is None or hi is None or lo > hi or lo == math.inf or hi == -math.inf:
        return
    if x0 is not None and not lo <= x0 <= hi:
        raise _error(spec, f"initial value {x0:g} of `{s.name}` is outside its bounds [{lo:g}, {hi:g}]; fix the "
                     "initial value or widen the bounds", s.initial.loc)
    if xf is not None and not lo <= xf <= hi:
        raise _error(spec, f"required final value {xf:g} of `{s.name}` is outside its bounds [{lo:g}, {hi:g}]",
                     s.final.loc)


def _check_value(spec: ProblemSpec, field: str, e: sympy.Expr, src) -> None:
    """An expression of the dynamics, costs or path constraints: a finite real value, not a condition."""
    # AccumBounds: what sympy makes of sin(inf) or cos(inf), which no code can print
    if e.has(sympy.zoo, sympy.nan, sympy.AccumBounds) or e.has(sympy.oo) or e.has(-sympy.oo):
        raise _error(spec, f"`{field}` evaluates to an infinite or undefined value (e.g. a division by zero); "
                     "check the expression", src.loc)
    if e.has(sympy.I):
        raise _error(spec, f"`{field}` is complex-valued; check the expression", src.loc)
    bad = _non_real_constant(e)
    if bad is not None:
        raise _error(spec, f"the constant `{bad}` has no finite real value (the generated code would compute NaN "
                     "or inf); check the arguments of its functions", src.loc)
    if e.is_Relational or isinstance(e, (sympy.logic.boolalg.BooleanFunction, sympy.logic.boolalg.BooleanAtom)):
        raise _error(spec, f"`{field}` is a condition, not a value; use where(cond, a, b)", src.loc)


def _check_free_horizon(sym: SymbolicProblem) -> None:
    """0 < lower <= guess <= upper, all finite: the transcriptions scale time by T within these bounds."""
    spec, free = sym.spec, sym.spec.free_horizon
    lo, hi = sym.horizon_bounds
    if lo is None or hi is None:
        return
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise _error(spec, f"bounds of the free final time are [{lo:g}, {hi:g}]; both must be finite (the final "
                     "time is scaled within them), e.g. `bounds: [0.5, 10]`", free.bounds_loc)
    if lo > hi:
        raise _error(spec, f"bounds of the free final time are reversed: lower {lo:g} > upper {hi:g}; write "
                     "`[lower, upper]`", free.bounds_loc)
    if not lo > 0:
        raise _error(spec, f"the lower bound of the free final time must be positive, got {lo:g}; a horizon of "
                     "zero length has no trajectory, e.g. `bounds: [0.1, 10]`", free.bounds_loc)
    g = sym.horizon
    if g is None:
        return
    if not math.isfinite(g):
        raise _error(spec, f"the guess of the free final time must be a finite number inside its bounds [{lo:g}, "
                     f"{hi:g}], got {g:g}", free.guess.loc)
    if not lo <= g <= hi:
        raise _error(spec, f"the guess {g:g} of the free final time is outside its bounds [{lo:g}, {hi:g}]; choose a "
                     "guess between them or widen the bounds", free.guess.loc)


def _check_path_constraint(sym: SymbolicProblem, c, e, lo: float | None, hi: float | None) -> None:
    """A path constraint: well-ordered bounds, at least one finite, and something a control can change."""
    spec = sym.spec
    if lo is not None and hi is not None:
        if lo == math.inf or hi == -math.inf:
            raise _error(spec, f"bounds of path constraint `{c.name}` are [{lo}, {hi}]: the lower bound cannot be "
                         "+inf nor the upper -inf; write `[lower, .inf]` or `[-.inf, upper]`", c.bounds_loc)
        if lo > hi:
            raise _error(spec, f"bounds of path constraint `{c.name}` are reversed: lower {lo:g} > upper {hi:g}; "
                         "write `[lower, upper]`", c.bounds_loc)
        if math.isinf(lo) and math.isinf(hi):
            raise _error(spec, f"path constraint `{c.name}` has bounds [-inf, inf], so it constrains nothing; give "
                         "one side a finite bound or remove the constraint", c.bounds_loc)
    if e is not None and not e.free_symbols & (set(sym.states) | set(sym.controls)):
        raise _error(spec, f"path constraint `{c.name}` uses no state or control, so no trajectory can change "
                     f"it (it is `{_show(str(e))}`); write an expression of the states and controls, or remove "
                     "it", c.expr.loc)


def _non_real_constant(e: sympy.Expr) -> sympy.Expr | None:
    """The first constant subexpression (no symbols) whose value is not a finite float64 real, else None.

    sympy keeps e.g. ``acos(2)`` or ``(-8)**(1/3)`` unevaluated (they are complex), and may wrap them in a function
    that is real again (``abs(acos(2))``), so the whole expression looks fine while the generated code computes
    NaN at the inner call. Every constant function application and power is evaluated numerically instead; one
    beyond the float64 range (``exp(1000)``) would be infinite in the generated code, so it counts too.
    """
    for sub in sympy.preorder_traversal(e):
        if sub.free_symbols or not isinstance(sub, (sympy.Function, sympy.Pow)):
            continue
        value = sub.evalf(30)
        if value.has(sympy.I, sympy.nan, sympy.zoo) or (value.is_Number and not math.isfinite(float(value))):
            return sub
    return None
