"""What a problem card shows of the schema 2 fields: a free final time and path constraints.

A schema 1 spec gets nothing from here (empty lists, the fixed-horizon sentence and its fingerprint unchanged), so the
committed cards of the schema 1 specs keep their bytes.
"""

from __future__ import annotations

import math

import sympy

from .card_text import _table, _value, code, md, num
from .lower import path_kind
from .schema import SymbolicProblem

__all__ = ["fingerprint_parts", "horizon_cell", "horizon_sentence", "path_lines", "path_table"]


def fingerprint_parts(sym: SymbolicProblem) -> list[str]:
    """The schema 2 mathematics for the card fingerprint; none for a problem without these fields."""
    if not sym.free_horizon and not sym.path:
        return []
    parts = [f"free horizon {sym.horizon_bounds!r}" if sym.free_horizon else "fixed horizon"]
    for c, e, lo, hi in zip(sym.spec.path_constraints, sym.path, sym.path_lower, sym.path_upper):
        parts.append(f"path {c.name} {lo!r} {hi!r} {sympy.srepr(e)}")
    return parts


def horizon_sentence(sym: SymbolicProblem) -> str:
    s = sym.spec
    if not sym.free_horizon:
        return f"Horizon T = {_value(sym.horizon, s.horizon)}"
    free = s.free_horizon
    return (f"Final time T free: a decision variable in [{_value(sym.horizon_bounds[0], free.lower)}, "
            f"{_value(sym.horizon_bounds[1], free.upper)}], guess {_value(sym.horizon, s.horizon)} (the transcriptions "
            "solve on t = T tau, tau in [0, 1])")


def horizon_cell(sym: SymbolicProblem) -> str:
    """T in the index table."""
    return f"free in [{num(sym.horizon_bounds[0])}, {num(sym.horizon_bounds[1])}]" if sym.free_horizon \
        else num(sym.horizon)


def path_lines(sym: SymbolicProblem, tex) -> tuple[str, ...]:
    """One LaTeX line per path constraint, ``lower <= g <= upper`` (an infinite side left out), for an aligned
    block."""
    lines = []
    for c, e, lo, hi in zip(sym.spec.path_constraints, sym.path, sym.path_lower, sym.path_upper):
        g = tex(e)
        if lo == hi:
            body = rf"{g} = {tex(_number(lo))}"
        else:
            left = "" if math.isinf(lo) else rf"{tex(_number(lo))} \le "
            right = "" if math.isinf(hi) else rf" \le {tex(_number(hi))}"
            body = left + g + right
        name = c.name.replace("_", r"\_")
        lines.append(rf"&{body} \qquad \text{{({name})}}")
    return tuple(lines)


def _number(v: float):
    return sympy.Integer(int(v)) if float(v).is_integer() else sympy.Float(v)


def path_table(sym: SymbolicProblem) -> str:
    rows = [(code(c.name), path_kind(e, sym), f"[{_value(lo, c.lower)}, {_value(hi, c.upper)}]",
             md(c.description))
            for c, e, lo, hi in zip(sym.spec.path_constraints, sym.path, sym.path_lower, sym.path_upper)]
    return _table(("path constraint", "kind", "bounds", "description"), rows, optional=("description",))
