"""Pass 3, checks, for the schema 3 fields: the uncertainty agrees with the rest of the spec.

The values first: a range lo < hi, a standard deviation > 0, parameter bounds in order, alpha in (0, 1), a sample
count and seed in range, noise levels >= 0. Then the agreement: each distribution lies inside its parameter's
physical domain (`bounds:`) and holds its nominal value where its support is bounded; no parameter the compiler fixed
at compile time (``structural_params``) is uncertain; every scenario names each uncertain parameter and nothing else,
with values its distribution can take; `robust` has something to be robust to; noise is on declared states. The
parse pass (:mod:`.parse_schema3`) checked only structure and types. Every problem is recorded on its own.
"""

from __future__ import annotations

import math

import sympy

from .errors import ErrorLog, Location, SpecError
from .expressions import ExpressionParser
from .schema import Distribution, Parameter, SymbolicProblem

__all__ = ["MAX_SAMPLES", "check_uncertainty", "support"]

# A robust plan holds every scenario's whole trajectory at once: more than this is a typo, not a plan.
MAX_SAMPLES = 100_000
MAX_SEED = 2**32 - 1  # what every JAX PRNG implementation takes


def _error(sym: SymbolicProblem, message: str, loc: Location) -> SpecError:
    lines = sym.spec.lines
    return SpecError(message, loc, lines[loc.line - 1] if 0 < loc.line <= len(lines) else None)


def support(d: Distribution) -> tuple[float, float]:
    """The smallest interval holding every value ``d`` can take (lognormal: (0, inf), open at 0)."""
    if d.kind == "uniform":
        return d.args[0], d.args[1]
    if d.kind == "lognormal":
        return 0.0, math.inf
    if d.kind == "choice":
        return min(d.args), max(d.args)
    return -math.inf, math.inf


def _describe(d: Distribution) -> str:
    return f"{d.kind} [{', '.join(f'{a:g}' for a in d.args)}]"


def check_uncertainty(sym: SymbolicProblem, log: ErrorLog) -> None:
    """Record every disagreement between the schema 3 fields and the rest of the spec (nothing for schema 1, 2)."""
    spec = sym.spec
    valid = set()  # parameters whose distribution passed its own check: only these are compared with other values
    for p, value in zip(spec.parameters, sym.param_values):
        bounds_ok = p.bounds is not None and log.attempt(_check_param_bounds, sym, p)
        if bounds_ok and value is not None:
            log.attempt(_check_nominal_in_bounds, sym, p, value)
        if p.value.number is None and value is not None and any(q.uncertain for q in spec.parameters):
            log.attempt(_check_value_uses, sym, p)
        if p.uncertain is not None and log.attempt(_check_distribution, sym, p.name, p.uncertain):
            valid.add(p.name)
            log.attempt(_check_structural, sym, p)
            if p.bounds is None or bounds_ok:
                log.attempt(_check_domain, sym, p)
            if value is not None:
                log.attempt(_check_nominal, sym, p, value)
    uncertain = {p.name: p for p in spec.parameters if p.uncertain is not None}
    if spec.scenarios_loc is not None and not uncertain:
        log.add(_error(sym, "`scenarios` give values of the uncertain parameters, but no parameter is uncertain; add "
                       "`uncertain: {uniform: [lo, hi]}` (or another distribution) to the parameters they vary",
                       spec.scenarios_loc))
    elif spec.scenarios_loc is not None:
        for i, scenario in enumerate(spec.scenarios):
            _check_scenario(sym, i, scenario, uncertain, valid, log)
    if spec.robust is not None:
        _check_robust(sym, bool(uncertain), log)
    if spec.noise is not None:
        for level in (spec.noise.process or ()) + (spec.noise.observation or ()):
            log.attempt(_check_noise_state, sym, level)
            if level.level < 0:
                log.add(_error(sym, f"the {level.part} noise of `{level.state}` is {level.level:g}; a noise level is a "
                               f"standard deviation, so it must be >= 0 (write `{level.state}: {-level.level:g}`?)",
                               level.value_loc))


def _check_param_bounds(sym: SymbolicProblem, p: Parameter) -> bool:
    lo, hi = p.bounds
    if lo == math.inf or hi == -math.inf or lo > hi:
        raise _error(sym, f"bounds of parameter `{p.name}` are [{lo:g}, {hi:g}]: they must be `[lower, upper]` with "
                     "lower <= upper; write `.inf` for no upper bound, e.g. `[0, .inf]` for a positive one",
                     p.bounds_loc)
    return True


def _check_distribution(sym: SymbolicProblem, name: str, d: Distribution) -> bool:
    """A distribution's own numbers: a uniform's lo < hi, a normal's std and a lognormal's sigma > 0."""
    if d.kind == "uniform" and not d.args[0] < d.args[1]:
        raise _error(sym, f"`uniform` of `{name}` is [{d.args[0]:g}, {d.args[1]:g}]: it needs lo < hi (a range with "
                     "something in it); write `[lo, hi]`, or drop `uncertain` for a known value", d.loc)
    if d.kind in ("normal", "lognormal") and not d.args[1] > 0:
        what = "std" if d.kind == "normal" else "sigma"
        raise _error(sym, f"`{d.kind}` of `{name}` has {what} {d.args[1]:g}; it must be positive, e.g. "
                     f"`[{d.args[0]:g}, 0.1]` (drop `uncertain` for a known value)", d.arg_locs[1])
    return True


def _check_nominal_in_bounds(sym: SymbolicProblem, p: Parameter, value: float) -> None:
    lo, hi = p.bounds
    if not lo <= value <= hi:
        raise _error(sym, f"the value {value:g} of `{p.name}` is outside its bounds [{lo:g}, {hi:g}]; fix the value "
                     "or the bounds", p.value.loc)


def _check_domain(sym: SymbolicProblem, p: Parameter) -> None:
    """The distribution takes only values inside the parameter's declared `bounds`."""
    if p.bounds is None:
        return
    d, (lo, hi) = p.uncertain, p.bounds
    s_lo, s_hi = support(d)
    if d.kind == "choice":
        outside = [v for v in d.args if not lo <= v <= hi]
        if outside:
            raise _error(sym, f"`choice` of `{p.name}` includes {', '.join(f'{v:g}' for v in outside)}, outside its "
                         f"bounds [{lo:g}, {hi:g}]; every choice must be a value the parameter can take", d.loc)
        return
    if lo <= s_lo and s_hi <= hi:
        return
    hint = {
        "normal": "a normal distribution takes every real value: use a `uniform` inside the bounds, or a `lognormal` "
                  "for a positive parameter",
        "lognormal": "a lognormal takes every positive value: use a `uniform` inside the bounds",
        "uniform": f"shrink the range into [{lo:g}, {hi:g}]",
    }[d.kind]
    raise _error(sym, f"`{_describe(d)}` of `{p.name}` takes values in ({s_lo:g}, {s_hi:g}), outside its bounds "
                 f"[{lo:g}, {hi:g}]; {hint}", d.loc)


def _check_value_uses(sym: SymbolicProblem, p: Parameter) -> None:
    """A parameter's value written with an uncertain parameter is evaluated at its nominal value: the two would not
    move together when one is drawn (each parameter is its own leaf)."""
    spec = sym.spec
    earlier = {q.name: sympy.Symbol(q.name, real=True) for q in spec.parameters[:spec.parameters.index(p)]}
    try:
        used = ExpressionParser(earlier, spec.lines, "").parse(p.value).free_symbols
    except SpecError:  # its numbers were read (value is not None); names that fail to read are not ours to report
        return
    drawn = [q.name for q in spec.parameters if q.uncertain is not None and earlier.get(q.name) in used]
    if drawn:
        names = ", ".join(f"`{n}`" for n in drawn)
        raise _error(sym, f"the value of `{p.name}` uses the uncertain parameter(s) {names}, so it is fixed at their "
                     f"nominal values and would not move with a draw; write `{p.name}` as a definition (definitions "
                     "follow the parameters they use), or give it a number", p.value.loc)


def _check_structural(sym: SymbolicProblem, p: Parameter) -> None:
    if p.name in sym.structural_params:
        raise _error(sym, f"`{p.name}` cannot be uncertain: initial values, bounds, final values or the horizon were "
                     f"evaluated with it at compile time, so a drawn value would leave them at the nominal {p.name}; "
                     "write those fields without it, or drop `uncertain`", p.uncertain.loc)


def _check_nominal(sym: SymbolicProblem, p: Parameter, value: float) -> None:
    """The nominal value is one the distribution can take where its support is bounded: the nominal problem is then
    one of the uncertain ones, and a plan for it a fair baseline for the robust plan."""
    d = p.uncertain
    if d.kind == "uniform" and not d.args[0] <= value <= d.args[1]:
        raise _error(sym, f"the value {value:g} of `{p.name}` is outside its uniform range [{d.args[0]:g}, "
                     f"{d.args[1]:g}]: the nominal problem would be one that cannot occur, so the nominal plan is no "
                     "baseline; move the value into the range or widen it", p.value.loc)
    if d.kind == "lognormal" and not value > 0:
        raise _error(sym, f"the value {value:g} of `{p.name}` is not positive, but its lognormal takes only positive "
                     "values; give a positive value or another distribution", p.value.loc)


def _check_scenario(sym: SymbolicProblem, i: int, scenario, uncertain: dict[str, Parameter], valid: set[str],
                    log: ErrorLog) -> None:
    """One scenario: only uncertain parameters, each of them, with a value its distribution and bounds allow."""
    declared = {p.name for p in sym.spec.parameters}
    named = set()
    for name, value, loc in scenario.values:
        named.add(name)
        if name not in declared:
            listed = ", ".join(uncertain)
            log.add(_error(sym, f"scenario {i + 1} names `{name}`, which is not a parameter; the uncertain parameters "
                           f"are {listed}", loc))
        elif name not in uncertain:
            log.add(_error(sym, f"scenario {i + 1} gives `{name}`, which is not uncertain (a scenario holds values of "
                           f"the uncertain parameters only); add `uncertain:` to `{name}` or remove it here", loc))
        elif name in valid:
            log.attempt(_check_scenario_value, sym, i, uncertain[name], value, loc)
    missing = [n for n in uncertain if n not in named]
    if missing:
        example = ", ".join(f"{n}: {_nominal(sym, n):g}" for n in missing)
        log.add(_error(sym, f"scenario {i + 1} leaves out the uncertain parameter(s) {', '.join(missing)}; every "
                       f"scenario gives each of them a value: add `{example}`", scenario.loc))


def _nominal(sym: SymbolicProblem, name: str) -> float:
    value = dict(zip((p.name for p in sym.spec.parameters), sym.param_values)).get(name)
    return math.nan if value is None else value


def _check_scenario_value(sym: SymbolicProblem, i: int, p: Parameter, value: float, loc: Location) -> None:
    d = p.uncertain
    if d.kind == "choice" and value not in d.args:
        raise _error(sym, f"scenario {i + 1} gives `{p.name}` = {value:g}, which is not one of its choices "
                     f"{list(d.args)}", loc)
    lo, hi = support(d)
    if not lo <= value <= hi or (d.kind == "lognormal" and value <= 0):
        raise _error(sym, f"scenario {i + 1} gives `{p.name}` = {value:g}, which its `{_describe(d)}` cannot take; "
                     "use a value it can", loc)
    # Inside the distribution's support is inside the parameter's bounds: _check_domain holds the one in the other.


def _check_robust(sym: SymbolicProblem, any_uncertain: bool, log: ErrorLog) -> None:
    spec, robust = sym.spec, sym.spec.robust
    if robust.alpha is not None and not 0 < robust.alpha < 1:
        log.add(_error(sym, f"cvar's alpha must be strictly between 0 and 1 (the fraction of the best scenario costs "
                       f"left out: 0 would be the mean, 1 the worst case), got {robust.alpha:g}; e.g. "
                       "`{cvar: 0.9}`, or write `mean` or `worst`", robust.alpha_loc))
    for key, value, lo, hi, why in (
            ("samples", robust.samples, 1, MAX_SAMPLES, "the number of scenarios drawn for the robust plan"),
            ("seed", robust.seed, 0, MAX_SEED, "the seed they are drawn with")):
        loc = robust.samples_loc if key == "samples" else robust.seed_loc
        if loc is not None and not lo <= value <= hi:
            log.add(_error(sym, f"`{key}` ({why}) must be a whole number from {lo} to {hi:,}, got {value}", loc))
    if not any_uncertain:
        log.add(_error(sym, "`robust` plans for the uncertain parameters, but no parameter is uncertain; add "
                       "`uncertain:` to a parameter, or remove `robust`", robust.loc))
        return
    if spec.scenarios_loc is None:
        return
    for key, loc in (("samples", robust.samples_loc), ("seed", robust.seed_loc)):
        if loc is not None:
            log.add(_error(sym, f"`{key}` is not used: the robust plan takes the explicit `scenarios` (`samples` and "
                           f"`seed` draw scenarios only without them); remove `{key}` or `scenarios`", loc))


def _check_noise_state(sym: SymbolicProblem, level) -> None:
    spec = sym.spec
    states = [s.name for s in spec.states]
    if level.state in states:
        return
    kind = ("a control: noise is on states (add it to the dynamics through a state)"
            if level.state in {c.name for c in spec.controls} else f"not a state; the states are {', '.join(states)}")
    raise _error(sym, f"noise on `{level.state}`, which is {kind}", level.loc)
