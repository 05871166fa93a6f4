"""Pass 4, lower: the checked symbolic problem → :class:`CodegenData` (every decision made, every string printed).

Prints, in minimisation form, f, L, φ and their Jacobians, and the Hamiltonian, costate equations and u* that
:mod:`.optimal_control` derives (u* only where it has a closed form, with the reason otherwise), plus the metadata
literals and the `myriadc show` summary. Shared subexpressions are factored by ``sympy.cse`` with deterministic names.
"""

from __future__ import annotations

import dataclasses
import math

import sympy

from .errors import CodegenError
from .optimal_control import Derived, _d, derive
from .parse_schema3 import DEFAULT_SAMPLES, DEFAULT_SEED
from .printer import StrictJaxPrinter
from .schema import CodegenData, CodegenFunction, SymbolicProblem

# derive and Derived live in .optimal_control; re-exported for existing importers.
__all__ = ["Derived", "class_name", "derive", "lower", "schema3_attributes"]


def class_name(system_name: str) -> str:
    return "".join(part[:1].upper() + part[1:] for part in system_name.split("_") if part) or "System_"


# ---- code generation -------------------------------------------------------------------------------------------

_ARGS = {
    "x": ("_x", "state vector, shape (n_states,)"),
    "u": ("_u", "control vector, shape (n_controls,)"),
    "lam": ("_lam", "costate vector, shape (n_states,)"),
    "t": ("_t", "time"),
    "p": ("_p", "parameters, a dict of scalars"),
}


def _function(name, doc, argkinds, outputs, shape, sym, derived, field) -> CodegenFunction:
    """Print one function: unpack used symbols, CSE temporaries, then the output (scalar, vector or matrix)."""
    flat = list(outputs) if shape != "matrix" else [e for row in outputs for e in row]
    temps, reduced = sympy.cse(flat, symbols=sympy.numbered_symbols("_c"), optimizations=None, order="canonical")
    used = set().union(*(e.free_symbols for e in reduced), *(e.free_symbols for _, e in temps)) if flat else set()
    unpack = []
    if "x" in argkinds:
        unpack += [(str(s), f"_x[{i}]") for i, s in enumerate(sym.states) if s in used]
    if "u" in argkinds:
        unpack += [(str(s), f"_u[{i}]") for i, s in enumerate(sym.controls) if s in used]
    if "lam" in argkinds:
        unpack += [(str(s), f"_lam[{i}]") for i, s in enumerate(derived.lam) if s in used]
    if "t" in argkinds and sym.time in used:
        unpack.append(("t", "_t"))
    unpack += [(str(s), f"_p[{str(s)!r}]") for s in sym.params if s in used]
    allowed = {sympy.Symbol(n, real=True) for n, _ in unpack} | {s for s, _ in temps}
    stray = used - allowed
    if stray:
        err = CodegenError(f"{field} depends on {', '.join(sorted(map(str, stray)))}, which {name} does not take")
        err.field = field
        raise err

    printer = StrictJaxPrinter().for_field(field)
    temp_lines = tuple((str(s), printer.doprint(e)) for s, e in temps)

    def out(e):
        # Constants print as floats so arrays built from them are floating point, never integer.
        if not e.free_symbols:
            return repr(float(e)) if e.is_number and e.is_finite else printer.doprint(e)
        return printer.doprint(e)

    if shape == "scalar":
        e = reduced[0]
        result = out(e) if e.free_symbols else f"jax.numpy.asarray({out(e)})"
    elif shape == "vector":
        result = "jax.numpy.array([" + ", ".join(out(e) for e in reduced) + "])"
    else:
        ncols = len(outputs[0]) if outputs else 0
        rows = [reduced[i * ncols:(i + 1) * ncols] for i in range(len(outputs))]
        result = "jax.numpy.array([" + ", ".join("[" + ", ".join(out(e) for e in r) + "]" for r in rows) + "])"
    args = tuple(_ARGS[k][0] for k in argkinds)
    return CodegenFunction(name=name, doc=doc, args=args, unpack=tuple(unpack), temps=temp_lines, result=result)


def _lit(v) -> str:
    """A Python literal for metadata; text goes through repr so it can never break out of the literal."""
    if v is None:
        return "None"
    if isinstance(v, bool):
        return repr(v)
    if isinstance(v, float):
        if math.isinf(v):
            return "math.inf" if v > 0 else "-math.inf"
        if math.isnan(v):
            return "math.nan"
        return repr(v)
    if isinstance(v, (int, str)):
        return repr(v)
    if isinstance(v, tuple):
        if len(v) == 1:
            return f"({_lit(v[0])},)"
        return "(" + ", ".join(_lit(x) for x in v) + ")"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_lit(k)}: {_lit(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def path_kind(expr, sym: SymbolicProblem) -> str:
    """"state" (no control in it: a pure state constraint), "control" (no state) or "mixed"."""
    has_x, has_u = bool(expr.free_symbols & set(sym.states)), bool(expr.free_symbols & set(sym.controls))
    return "mixed" if has_x and has_u else ("control" if has_u else "state")


def _schema2_metadata(sym: SymbolicProblem) -> tuple[tuple[str, str], ...]:
    """The schema 2 attributes, written only into schema 2 modules: a schema 1 module keeps its bytes and inherits
    the same values as defaults from the runtime's System."""
    spec = sym.spec
    if spec.schema < 2:
        return ()
    return (
        ("free_horizon", _lit(sym.free_horizon)),
        ("horizon_bounds", _lit(sym.horizon_bounds)),
        ("horizon_guess", _lit(sym.horizon if sym.free_horizon else None)),
        ("path_constraint_names", _lit(tuple(c.name for c in spec.path_constraints))),
        ("path_constraint_descriptions", _lit(tuple(c.description for c in spec.path_constraints))),
        ("path_constraint_kinds", _lit(tuple(path_kind(e, sym) for e in sym.path))),
        ("path_lower", _lit(sym.path_lower)),
        ("path_upper", _lit(sym.path_upper)),
    )


def schema3_attributes(sym: SymbolicProblem) -> tuple[tuple[str, object], ...]:
    """The schema 3 attributes (the interface of issue 30, declared in runtime/system.py) as ``(name, value)``, for
    a schema 3 problem; none for an earlier schema's."""
    spec = sym.spec
    if spec.schema < 3:
        return ()
    uncertain = [p for p in spec.parameters if p.uncertain is not None]
    order = [p.name for p in uncertain]
    rows = tuple(tuple(float(dict((n, v) for n, v, _ in s.values)[name]) for name in order) for s in spec.scenarios)
    robust, noise = spec.robust, spec.noise

    def per_state(levels):
        if levels is None:
            return ()
        given = {lv.state: lv.level for lv in levels}
        return tuple(float(given.get(s.name, 0.0)) for s in spec.states)

    return (
        ("uncertain_params", tuple(order)),
        ("uncertain_kinds", tuple(p.uncertain.kind for p in uncertain)),
        ("uncertain_args", tuple(tuple(float(a) for a in p.uncertain.args) for p in uncertain)),
        ("scenarios", rows),
        ("robust_objective", robust.objective if robust else None),
        ("robust_alpha", robust.alpha if robust else None),
        ("robust_samples", robust.samples if robust else DEFAULT_SAMPLES),
        ("robust_seed", robust.seed if robust else DEFAULT_SEED),
        ("process_noise", per_state(noise.process if noise else None)),
        ("observation_noise", per_state(noise.observation if noise else None)),
    )


def _schema3_metadata(sym: SymbolicProblem) -> tuple[tuple[str, str], ...]:
    """The schema 3 attributes, written only into schema 3 modules: an earlier schema's module keeps its bytes and
    inherits the empty defaults."""
    return tuple((name, _lit(value)) for name, value in schema3_attributes(sym))


def _path_functions(sym: SymbolicProblem, d) -> list[CodegenFunction]:
    """g(x, u, t, p) and its Jacobians; none without path constraints (the runtime's System returns empty arrays)."""
    if not sym.path:
        return []
    g, X, U = sym.path, sym.states, sym.controls
    try:
        return _path_function_list(sym, d, g, X, U)
    except CodegenError:
        # Name the constraint that cannot be printed, so the error points at its own expression.
        for c, gi in zip(sym.spec.path_constraints, g):
            field = f"path_constraints.{c.name}"
            _function("path_constraints", "", ("x", "u", "t", "p"), (gi,), "vector", sym, d, field)
            _function("path_constraints_jac_x", "", ("x", "u", "t", "p"), tuple(_d(gi, xj) for xj in X), "vector",
                      sym, d, field)
            _function("path_constraints_jac_u", "", ("x", "u", "t", "p"), tuple(_d(gi, uj) for uj in U), "vector",
                      sym, d, field)
        raise


def _path_function_list(sym, d, g, X, U) -> list[CodegenFunction]:
    return [
        _function("path_constraints", "g(x, u, t, p), shape (n_path,); path_lower <= g <= path_upper along the path.",
                  ("x", "u", "t", "p"), g, "vector", sym, d, "path_constraints"),
        _function("path_constraints_jac_x", "dg/dx, shape (n_path, n_states).", ("x", "u", "t", "p"),
                  tuple(tuple(_d(gi, xj) for xj in X) for gi in g), "matrix", sym, d, "path_constraints"),
        _function("path_constraints_jac_u", "dg/du, shape (n_path, n_controls).", ("x", "u", "t", "p"),
                  tuple(tuple(_d(gi, uj) for uj in U) for gi in g), "matrix", sym, d, "path_constraints"),
    ]


def safe_comment(text: str) -> str:
    """Text for a generated comment: one line of printable ASCII."""
    return "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in text)


def lower(sym: SymbolicProblem, display_path: str) -> CodegenData:
    spec = sym.spec
    fns, d = _functions(sym, derive(sym))
    metadata = _metadata(sym, d, display_path)
    summary = _summary(sym, d)
    header = (f"Autogenerated by myriadc from {safe_comment(display_path)} (schema {spec.schema}, sha256 "
              f"{spec.sha256}). Do not edit.")
    return CodegenData(
        header=header,
        module_doc=_lit(f"{spec.title}: generated JAX system (minimisation form).\n\n{spec.description}"),
        class_name=class_name(spec.name),
        # `math` only where a literal needs it (an infinite bound), so no module imports what it does not use.
        imports=(("import math", "") if any("math." in lit for _, lit in metadata) else ())
        + ("import jax.numpy", "", "from myriad.runtime.system import System as _System"),
        metadata=metadata,
        functions=tuple(fns),
        summary=tuple(summary),
    )


def _functions(sym: SymbolicProblem, d):
    """The generated functions, and the derivation (its u* dropped, with the reason, where u* cannot be printed)."""
    X, U = sym.states, sym.controls
    fns = [
        _function("dynamics", "f(x, u, t, p): the state derivative, shape (n_states,).",
                  ("x", "u", "t", "p"), d.f, "vector", sym, d, "dynamics"),
        _function("running_cost", "L(x, u, t, p), minimisation form.",
                  ("x", "u", "t", "p"), (d.L,), "scalar", sym, d, "cost.running"),
        _function("terminal_cost", "phi(x, t, p) at the final time, minimisation form.",
                  ("x", "t", "p"), (d.phi,), "scalar", sym, d, "cost.terminal"),
        _function("dynamics_jac_x", "df/dx, shape (n_states, n_states).", ("x", "u", "t", "p"),
                  tuple(tuple(_d(fi, xj) for xj in X) for fi in d.f), "matrix", sym, d, "dynamics"),
        _function("dynamics_jac_u", "df/du, shape (n_states, n_controls).", ("x", "u", "t", "p"),
                  tuple(tuple(_d(fi, uj) for uj in U) for fi in d.f), "matrix", sym, d, "dynamics"),
        _function("running_cost_grad_x", "dL/dx, shape (n_states,).", ("x", "u", "t", "p"),
                  tuple(_d(d.L, xj) for xj in X), "vector", sym, d, "cost.running"),
        _function("running_cost_grad_u", "dL/du, shape (n_controls,).", ("x", "u", "t", "p"),
                  tuple(_d(d.L, uj) for uj in U), "vector", sym, d, "cost.running"),
        _function("terminal_cost_grad_x", "dphi/dx, shape (n_states,).", ("x", "t", "p"),
                  d.terminal_costate, "vector", sym, d, "cost.terminal"),
        _function("hamiltonian", "H = L + lam . f, minimisation form.", ("x", "u", "lam", "t", "p"),
                  (d.H,), "scalar", sym, d, "hamiltonian"),
        _function("costate_dynamics", "lam' = -dH/dx, shape (n_states,).", ("x", "u", "lam", "t", "p"),
                  d.costate, "vector", sym, d, "costate"),
        _function("hamiltonian_grad_u", "dH/du, shape (n_controls,).", ("x", "u", "lam", "t", "p"),
                  d.dH_du, "vector", sym, d, "hamiltonian"),
        _function("terminal_costate", "lam(T) = dphi/dx(x(T)) for free final states, shape (n_states,).",
                  ("x", "t", "p"), d.terminal_costate, "vector", sym, d, "cost.terminal"),
    ]
    if d.u_star is not None:
        try:
            fns.append(_function("optimal_control", f"u*(x, lam, t, p), {d.u_star_kind}: {d.u_star_note}.",
                                 ("x", "lam", "t", "p"), d.u_star, "vector", sym, d, "optimal_control"))
        except CodegenError as exc:  # u* is optional: the system still compiles, the sweep then refuses it
            d = dataclasses.replace(d, u_star=None, u_star_kind="none", u_star_note=f"u* cannot be printed: {exc}")

    fns += _path_functions(sym, d)
    return fns, d


def _metadata(sym: SymbolicProblem, d, display_path: str) -> tuple:
    """The generated class's attributes: ``(name, Python literal)`` pairs."""
    spec = sym.spec
    learnable = tuple(p.name for p in spec.parameters if p.learnable)
    guesses = tuple(g for p, g in zip(spec.parameters, sym.guesses) if p.learnable)
    used_t = sym.time in (set().union(*(e.free_symbols for e in d.f)) | d.L.free_symbols)
    return (
        ("name", _lit(spec.name)),
        ("title", _lit(spec.title)),
        ("description", _lit(spec.description)),
        ("source", _lit(spec.source)),
        ("spec_file", _lit(display_path)),
        ("spec_sha256", _lit(spec.sha256)),
        ("schema", _lit(spec.schema)),
        ("sense", _lit(spec.sense)),
        ("horizon", _lit(sym.horizon)),
        *_schema2_metadata(sym),
        ("state_names", _lit(tuple(s.name for s in spec.states))),
        ("state_descriptions", _lit(tuple(s.description for s in spec.states))),
        ("state_units", _lit(tuple(s.units for s in spec.states))),
        ("control_names", _lit(tuple(c.name for c in spec.controls))),
        ("control_descriptions", _lit(tuple(c.description for c in spec.controls))),
        ("control_units", _lit(tuple(c.units for c in spec.controls))),
        ("param_names", _lit(tuple(p.name for p in spec.parameters))),
        ("param_values", _lit(sym.param_values)),
        ("param_descriptions", _lit(tuple(p.description for p in spec.parameters))),
        ("learnable", _lit(learnable)),
        ("learnable_guesses", _lit(guesses)),
        ("structural_params", _lit(sym.structural_params)),
        ("x0", _lit(sym.x0)),
        ("x_lower", _lit(sym.x_lower)),
        ("x_upper", _lit(sym.x_upper)),
        ("u_lower", _lit(sym.u_lower)),
        ("u_upper", _lit(sym.u_upper)),
        ("x_final", _lit(sym.x_final)),
        ("has_terminal_cost", _lit(spec.terminal is not None)),
        ("time_dependent", _lit(bool(used_t))),
        ("optimal_control_kind", _lit(d.u_star_kind)),
        ("optimal_control_note", _lit(d.u_star_note)),
        ("reference", _lit(dict(spec.reference))),
        *_schema3_metadata(sym),
    )


def _summary(sym: SymbolicProblem, d) -> list:
    """``(label, equation)`` rows of `myriadc show` and the module's docstring, costates named ``lam_x``."""
    spec, X, U = sym.spec, sym.states, sym.controls
    lam_names = {str(lam): f"lam_{x}" for lam, x in zip(d.lam, X)}

    def show(e):
        text = sympy.sstr(e)
        for k in sorted(lam_names, key=len, reverse=True):
            text = text.replace(k, lam_names[k])
        return text

    summary = [(f"d{x}/dt", show(fi)) for x, fi in zip(X, d.f)]
    summary += [("L", show(d.L)), ("phi", show(d.phi)), ("H", show(d.H))]
    summary += [(f"d{lam_names[str(lam)]}/dt", show(c)) for lam, c in zip(d.lam, d.costate)]
    summary += [(f"{lam_names[str(lam)]}(T)", show(c) if xf is None else f"free: {x}(T) = {xf:g} is required")
                for lam, c, x, xf in zip(d.lam, d.terminal_costate, X, sym.x_final)]
    if sym.free_horizon:
        # Free final time: the transversality condition H(T) + dphi/dT = 0 (phi's `t` is the final time).
        summary.append(("H(T)", f"{show(-_d(d.phi, sym.time))} (free final time in [{sym.horizon_bounds[0]:g}, "
                                f"{sym.horizon_bounds[1]:g}])"))
    summary += [(f"path {c.name}", f"{lo:g} <= {show(e)} <= {hi:g}")
                for c, e, lo, hi in zip(spec.path_constraints, sym.path, sym.path_lower, sym.path_upper)]
    if d.u_star is None:
        summary.append(("u*", f"not derived: {d.u_star_note}"))
    else:
        summary += [(f"{u}* ({d.u_star_kind})", show(e)) for u, e in zip(U, d.u_star)]

    return summary
