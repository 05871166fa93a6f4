"""What a problem card and `myriadc show` print of the schema 3 fields: the uncertainty.

A table of the uncertain parameters (nominal value, distribution, bounds), the explicit scenarios, the robust
objective and the noise. A schema 1 or 2 spec gets nothing from here, so its card and its `show` output keep their
bytes; the card fingerprint (:func:`compiler.card.fingerprint`) leaves the uncertainty out, since the recorded results
are nominal solves that it does not change.
"""

from __future__ import annotations

from .card_text import _table, code, num
from .schema import Distribution, SymbolicProblem

__all__ = ["describe", "robust_sentence", "show_lines", "uncertainty_blocks"]

def describe(d: Distribution) -> str:
    """One distribution in words and numbers, e.g. ``uniform on [1.5, 2.5]``."""
    a = d.args
    if d.kind == "uniform":
        return f"uniform on [{num(a[0])}, {num(a[1])}]"
    if d.kind == "normal":
        return f"normal, mean {num(a[0])}, std {num(a[1])}"
    if d.kind == "lognormal":
        return f"lognormal, log-mean {num(a[0])}, log-std {num(a[1])} (its log is normal)"
    return "one of " + ", ".join(num(v) for v in a) + " (equally likely)"


def robust_sentence(sym: SymbolicProblem) -> str:
    """The robust objective and the scenarios it is taken over, or that none is declared."""
    spec, robust = sym.spec, sym.spec.robust
    n = len(spec.scenarios)
    over = (f"the {n} explicit scenario{'s' if n != 1 else ''}" if n else
            f"{robust.samples} scenarios drawn from the distributions (seed {robust.seed})" if robust else "")
    if robust is None:
        return (f"Scenarios: {over}; no `robust:` objective is declared." if n else
                "No robust objective is declared (no `robust:`, no `scenarios:`).")
    what = {"mean": "the mean of the scenario costs", "worst": "the worst scenario cost (epigraph)",
            "cvar": f"the CVaR at alpha = {num(robust.alpha)} of the scenario costs (Rockafellar-Uryasev)"}
    return f"Robust objective: {what[robust.objective]}, over {over}."


def _noise_rows(sym: SymbolicProblem) -> list[tuple[str, str, str]]:
    noise = sym.spec.noise
    if noise is None:
        return []
    process = {lv.state: lv.level for lv in noise.process or ()}
    observation = {lv.state: lv.level for lv in noise.observation or ()}
    # 0 where a part lists other states but not this one (no noise there); "-" where the part is absent.
    return [(s.name, num(process.get(s.name, 0.0)) if noise.process else "-",
             num(observation.get(s.name, 0.0)) if noise.observation else "-")
            for s in sym.spec.states if s.name in process or s.name in observation]


def _uncertain(sym: SymbolicProblem):
    return [(p, v) for p, v in zip(sym.spec.parameters, sym.param_values) if p.uncertain is not None]


def uncertainty_blocks(sym: SymbolicProblem) -> list[str]:
    """The card's "Uncertainty" section (Markdown blocks); empty for a schema 1 or 2 spec."""
    spec = sym.spec
    if spec.schema < 3:
        return []
    uncertain = _uncertain(sym)
    if not uncertain and spec.noise is None:
        return ["Nothing is declared uncertain and there is no noise."]
    blocks = []
    if uncertain:
        rows = [(code(p.name), num(v), describe(p.uncertain),
                 f"[{num(p.bounds[0])}, {num(p.bounds[1])}]" if p.bounds else "") for p, v in uncertain]
        blocks.append(_table(("parameter", "nominal", "distribution", "bounds"), rows, optional=("bounds",)))
    if spec.scenarios:
        names = [p.name for p, _ in uncertain]
        rows = [(str(i + 1), *(num(dict((n, v) for n, v, _ in s.values)[name]) for name in names))
                for i, s in enumerate(spec.scenarios)]
        blocks.append(_table(("scenario", *(code(n) for n in names)), rows))
    if uncertain:
        blocks.append(robust_sentence(sym))
    rows = _noise_rows(sym)
    if rows:
        blocks.append("Noise: process noise sigma enters as dx = f dt + sigma dW (Ito); observation noise is additive "
                      "with the given standard deviation.")
        blocks.append(_table(("state", "process sigma", "observation std"), [(code(s), p, o) for s, p, o in rows]))
    return blocks


def show_lines(sym: SymbolicProblem) -> list[str]:
    """What `myriadc show` prints of the uncertainty, as lines of aligned plain text; none for schema 1 or 2."""
    if sym.spec.schema < 3:
        return []
    uncertain = _uncertain(sym)
    lines = []
    if uncertain:
        lines += ["  uncertain:"] + _columns([("parameter", "nominal", "distribution"),
                                             *((p.name, num(v), describe(p.uncertain)) for p, v in uncertain)])
    if sym.spec.scenarios:
        names = [p.name for p, _ in uncertain]
        rows = [(f"{i + 1}", *(num(dict((n, v) for n, v, _ in s.values)[name]) for name in names))
                for i, s in enumerate(sym.spec.scenarios)]
        lines += ["  scenarios:"] + _columns([("scenario", *names), *rows])
    if uncertain:
        lines.append(f"  {robust_sentence(sym)}")
    rows = _noise_rows(sym)
    if rows:
        lines += ["  noise:"] + _columns([("state", "process sigma", "observation std"),
                                         *rows])
    return lines or ["  nothing is declared uncertain, no noise"]


def _columns(rows: list[tuple[str, ...]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["    " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
