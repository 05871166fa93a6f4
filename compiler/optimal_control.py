"""The optimal-control derivations (Pontryagin's minimum principle), symbolically, in minimisation form.

From a checked :class:`SymbolicProblem` (a ``maximize`` spec's payoff is negated first), :func:`derive` forms
  * f, L, φ;
  * the Hamiltonian H = L + λ·f and the costate equations λ' = −∂H/∂x, with λ(T) = ∂φ/∂x(T);
  * the optimal-control characterisation: u* from ∂H/∂u = 0 when H is quadratic in u with a positive, decoupled
    curvature; the switching function's sign (bang-bang) when H is linear in u with finite bounds; else "none" and
    the reason. u* is clipped to the control bounds (exact for decoupled quadratics).
With path constraints (schema 2) H carries no multiplier terms: u* is withdrawn when a constraint involves a control
and kept, with a caveat, for pure state constraints (:func:`_with_path_constraints`). A free final time adds the
transversality condition H(T) = -dφ/dt(T), which lowering states in the summary.
Lowering (:mod:`.lower`) prints these, `myriadc show` displays them and the CasADi export starts from them; all
derivatives are taken almost everywhere by :func:`_d`.
"""

from __future__ import annotations

import dataclasses
import math

import sympy

from .schema import SymbolicProblem

__all__ = ["Derived", "derive"]


@dataclasses.dataclass(frozen=True)
class Derived:
    """The minimisation-form artefacts, as sympy (used by lowering, `myriadc show` and the tests)."""

    f: tuple
    L: object
    phi: object
    lam: tuple
    H: object
    costate: tuple
    dH_du: tuple
    terminal_costate: tuple
    u_star: tuple | None
    u_star_kind: str
    u_star_note: str


def _d(expr, var):
    """d expr / d var almost everywhere: the Dirac deltas that sign/Heaviside produce are zero off a null set (and
    cannot be printed), so they are dropped, as autodiff of the generated code would do."""
    out = sympy.diff(expr, var)
    if out.has(sympy.DiracDelta):
        out = out.replace(lambda e: isinstance(e, sympy.DiracDelta), lambda e: sympy.Integer(0))
    return out


def derive(sym: SymbolicProblem) -> Derived:
    """The minimisation-form artefacts of ``sym``; u* is None (kind "none", the note says why) without a closed form."""
    sign = 1 if sym.spec.sense == "minimize" else -1
    f = tuple(sym.dynamics)
    L = sign * sym.running
    phi = sign * sym.terminal
    lam = tuple(sympy.Symbol(f"_lam{i}", real=True) for i in range(len(sym.states)))
    H = L + sum((li * fi for li, fi in zip(lam, f)), sympy.Integer(0))
    costate = tuple(-_d(H, x) for x in sym.states)
    dH_du = tuple(_d(H, u) for u in sym.controls)
    terminal_costate = tuple(_d(phi, x) for x in sym.states)
    try:
        u_star, kind, note = _characterise(sym, H, dH_du)
    except (TypeError, ValueError, ZeroDivisionError) as exc:  # sympy could not decide a comparison or a sign
        u_star, kind, note = None, "none", f"u* could not be characterised symbolically ({type(exc).__name__})"
    if u_star is not None and any(e.free_symbols & set(sym.controls) for e in u_star):
        u_star, kind, note = None, "none", "dH/du = 0 has no closed form here (u* would still depend on u)"
    u_star, kind, note = _with_path_constraints(sym, u_star, kind, note)
    return Derived(f, L, phi, lam, H, costate, dH_du, terminal_costate, u_star, kind, note)


def _with_path_constraints(sym: SymbolicProblem, u_star, kind: str, note: str):
    """What survives of u* when the spec has path constraints (schema 2).

    H here has no multiplier terms for the path constraints. A constraint that involves a control turns the pointwise
    minimisation of H into a constrained one whose solution depends on which constraints are active: u* is then not
    derived. Pure state constraints leave u* = argmin H valid on arcs where none is active (the costates jump at the
    junctions, which the indirect method here does not model), so u* is kept with that caveat.
    """
    controls = set(sym.controls)
    mixed = [c.name for c, e in zip(sym.spec.path_constraints, sym.path) if e.free_symbols & controls]
    if mixed:
        return None, "none", (f"the path constraint(s) {', '.join(mixed)} involve the controls, so u* minimises H "
                              "subject to them and depends on which are active; use a direct transcription")
    if sym.path and u_star is not None:
        names = ", ".join(c.name for c in sym.spec.path_constraints)
        note += (f"; valid only on arcs where the state path constraint(s) {names} are inactive (the costates jump "
                 "where one becomes active)")
    return u_star, kind, note


def _characterise(sym: SymbolicProblem, H, dH_du):
    """u* minimising H over the control box, when it has a closed form; else (None, "none", reason)."""
    controls = sym.controls
    nominal = dict(zip(sym.params, sym.param_values))
    u_star, kinds = [], []
    for j, (u, g, lo, hi) in enumerate(zip(controls, dH_du, sym.u_lower, sym.u_upper)):
        curv = _d(g, u)
        if curv.free_symbols & set(controls):
            return None, "none", (f"H is neither linear nor quadratic in `{u}` (d2H/d{u}2 = {curv} depends on the "
                                  "controls), so dH/du = 0 has no closed form here; use a direct transcription")
        for k, v in enumerate(controls):
            if k != j and _d(g, v) != 0:
                return None, "none", (f"H couples the controls `{u}` and `{v}` (d2H/d{u}d{v} != 0); the indirect "
                                      "method here needs decoupled controls")
        if curv == 0:
            if math.isinf(lo) or math.isinf(hi):
                return None, "none", (f"H is linear in `{u}` but its bounds [{lo}, {hi}] are not finite: no "
                                      "minimiser exists")
            sigma = g  # switching function: H is increasing in u where sigma > 0, so u sits at its lower bound
            u_star.append(sympy.Piecewise((_num(lo), sigma > 0), (_num(hi), sigma < 0),
                                          (_num((lo + hi) / 2), True)))
            kinds.append("bang_bang")
            continue
        if curv.free_symbols - set(sym.params):
            return None, "none", (f"d2H/d{u}2 = {curv} depends on the state or costate; its sign (a minimum) cannot "
                                  "be guaranteed symbolically")
        if not float(curv.subs(nominal)) > 0:
            return None, "none", (f"d2H/d{u}2 = {curv} is not positive at the nominal parameters: dH/d{u} = 0 is "
                                  "not a minimum")
        free = -g.subs(u, 0) / curv
        u_star.append(sympy.Min(sympy.Max(free, _num(lo)), _num(hi)))
        kinds.append("stationary")
    kind = "bang_bang" if "bang_bang" in kinds else "stationary"
    if kind == "bang_bang":
        note = ("H is linear in " + ", ".join(str(u) for u, k in zip(controls, kinds) if k == "bang_bang")
                + ": u* = lower bound where the switching function dH/du > 0, upper bound where < 0, mid-box on a "
                "singular arc (dH/du = 0)")
    else:
        note = ("u* solves dH/du = 0 (H quadratic in u, positive curvature at the nominal parameters), "
                "clipped to the bounds")
    return tuple(u_star), kind, note


def _num(v: float):
    """A control bound as an exact sympy number: ±oo, an Integer, or a 17-digit Float (round-trips the float64)."""
    if math.isinf(v):
        return sympy.oo if v > 0 else -sympy.oo
    return sympy.Float(v, 17) if not float(v).is_integer() else sympy.Integer(int(v))
