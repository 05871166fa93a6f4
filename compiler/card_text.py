"""Markdown and LaTeX text for problem cards: spec prose made inert, numbers, symbols, tables and math blocks.

Everything here is pure text formatting (no spec semantics), shared by :mod:`.card` and :mod:`.card_schema2`.
"""

from __future__ import annotations

import math
import os
import re
import urllib.parse

import sympy
from sympy.printing.conventions import split_super_sub
from sympy.printing.latex import translate

__all__ = ["code", "md", "num", "symbol_tex"]

_SEPARATORS = re.compile(r"[\s\u2028\u2029\x85]+")
# `_` between two letters or digits is plain text in CommonMark (no intraword emphasis), so names stay readable.
_ESCAPE = re.compile(r"([\\`*\[\]<>|$~]|(?<![A-Za-z0-9])_|_(?![A-Za-z0-9]))")
_ENTITY = re.compile(r"&(?=#?\w+;)")


def md(text: str) -> str:
    """Spec prose as one line of inert Markdown: no HTML, links, emphasis, math, table cells or block starts."""
    text = "".join(ch if ch.isprintable() or ch.isspace() else "?" for ch in text)
    text = _SEPARATORS.sub(" ", text).strip()
    text = _ENTITY.sub(r"\\&", _ESCAPE.sub(r"\\\1", text))
    text = re.sub(r"\A(\d+)([.)])", r"\1\\\2", text)  # "1." would start an ordered list
    return "\\" + text if re.match(r"[#>+\-=]", text) else text


def code(text: str) -> str:
    """Expression text as a code span: backslash escapes do not work inside one, but a table still splits on `|`."""
    text = _SEPARATORS.sub(" ", "".join(ch if ch.isprintable() else "?" for ch in text)).strip()
    return "`" + text.replace("`", "'").replace("|", "\\|") + "`"


def _value(v: float | None, expr) -> str:
    """A constant as a number, followed by the spec's expression when it wrote one (`2*pi`, not just 6.283185307)."""
    if expr is None or expr.number is not None or v is None or math.isinf(v):
        return num(v)
    return f"{num(v)} ({code(expr.text)})"


def _url(path: str) -> str:
    """A relative path as a Markdown link target: a space or a parenthesis would end it early."""
    return urllib.parse.quote(path.replace(os.sep, "/"))


def _comment(text: str) -> str:
    """Text inside an HTML comment: printable ASCII that cannot close it."""
    return "".join(ch if 32 <= ord(ch) < 127 else "?" for ch in text).replace("--", "-?").replace(">", "?")


def num(v: float | None) -> str:
    if v is None:
        return "free"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.10g}"


_DOTS = {0: "{}", 1: r"\dot{{{}}}", 2: r"\ddot{{{}}}", 3: r"\dddot{{{}}}"}


def symbol_tex(name: str, dots: int = 0) -> str:
    """A declared name as LaTeX: greek letters, digits and ``_x`` as subscripts, ``_dot``/``dot`` as a dot accent
    (``q1_dot`` → q̇₁), other multi-letter names in ``\\mathit`` as one word (``power``, not p·o·w·e·r)."""
    base, sups, subs = split_super_sub(name)
    dots += sum(s == "dot" for s in subs) + 2 * sum(s == "ddot" for s in subs)
    subs = [s for s in subs if s not in ("dot", "ddot")]
    for suffix, n in (("ddot", 2), ("dot", 1)):
        if base.endswith(suffix) and len(base) > len(suffix):
            base, dots = base[: -len(suffix)], dots + n
            break
    tex = translate(base)
    if not tex.startswith("\\") and len(tex) > 1:
        tex = rf"\mathit{{{tex}}}"
    tex = _DOTS[min(dots, 3)].format(tex)

    def script(items):
        return ",".join(s if len(s) == 1 or s.isdigit() else rf"\mathrm{{{s}}}" for s in items)

    return tex + (f"_{{{script(subs)}}}" if subs else "") + (f"^{{{script(sups)}}}" if sups else "")


def _short_floats(e):
    # Control bounds enter u* as 17-digit Floats (exact float64 round trips); a reader wants 0.2, not 0.2000...01.
    return e.xreplace({f: sympy.Float(float(f)) for f in e.atoms(sympy.Float)})


def _table(head: tuple[str, ...], rows: list[tuple[str, ...]], optional: tuple[str, ...] = ()) -> str:
    """A GFM table; the ``optional`` columns are left out when no row has anything in them."""
    keep = [i for i, h in enumerate(head) if h not in optional or any(row[i] for row in rows)]
    head, rows = tuple(head[i] for i in keep), [tuple(row[i] for i in keep) for row in rows]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(c or " " for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _math(*lines: str, aligned: bool = False) -> str:
    body = " \\\\\n".join(lines)
    if aligned:
        body = f"\\begin{{aligned}}\n{body}\n\\end{{aligned}}"
    return f"```math\n{body}\n```"


def _g(v) -> str:
    return "-" if v is None else f"{v:.6g}"


def _e(v) -> str:
    return "-" if v is None else f"{v:.1e}"
