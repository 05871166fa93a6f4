"""Pass 1, parse, for the fields schema 3 adds: uncertain parameters, scenarios, a robust objective and noise.

Called by :mod:`.parse` with its reader (so positions and messages are the same as for every other field). The numbers
in these fields are YAML numbers, never expressions: the runtime samples from them as data, and nothing in them is
evaluated. Only the structure and the types are checked here (a distribution's kind and count of numbers, numbers
that are finite, whole numbers where counts are meant); the values (a standard deviation > 0, a range lo < hi, alpha in
(0, 1), a noise level >= 0) and what relates them to the rest of the spec (a scenario's names, a distribution inside
its parameter's domain, noise on a declared state) are checked by :mod:`.checks_schema3`, so all of them are reported
together.

    parameters:
      k: {value: 2.0, bounds: [0, .inf], uncertain: {uniform: [1.5, 2.5]}}
    scenarios: [{k: 1.5}, {k: 2.5}]
    robust: {objective: {cvar: 0.9}, samples: 16, seed: 0}
    noise: {process: {v: 0.05}, observation: {q: 0.01}}
"""

from __future__ import annotations

import math

import yaml

from .errors import Unresolved  # a field whose parts were already reported
from .schema import Distribution, Noise, NoiseLevel, Robust, Scenario

__all__ = ["DEFAULT_SAMPLES", "DEFAULT_SEED", "DISTRIBUTIONS", "ROBUST_OBJECTIVES", "SCHEMA3_PARAM_FIELDS",
           "SCHEMA3_TOP_FIELDS", "distribution", "noise", "number", "param_bounds", "require_schema3",
           "require_schema3_param", "robust", "scenarios"]

SCHEMA3_TOP_FIELDS = ("scenarios", "robust", "noise")
SCHEMA3_PARAM_FIELDS = ("uncertain", "bounds")
# kind -> (the names of its numbers, for messages; their count, None for any number of them)
DISTRIBUTIONS = {
    "uniform": ("[lo, hi]", 2),
    "normal": ("[mean, std]", 2),
    "lognormal": ("[mu, sigma]", 2),
    "choice": ("[v1, v2, ...]", None),
}
ROBUST_OBJECTIVES = ("mean", "worst", "cvar")
ROBUST_FIELDS = {"objective": False, "samples": False, "seed": False}  # `objective` gets a message of its own
NOISE_FIELDS = {"process": False, "observation": False}
DEFAULT_SAMPLES, DEFAULT_SEED = 16, 0
_KINDS = ", ".join(f"`{{{k}: {shape}}}`" for k, (shape, _) in DISTRIBUTIONS.items())


def _needs3(key: str, schema: int) -> str:
    return (f"`{key}` needs `schema: 3` (this file declares `schema: {schema}`); change the `schema:` line to "
            "`schema: 3`")


def require_schema3(r, schema: int, top: dict) -> None:
    """A schema 1 or 2 file that uses a schema 3 top-level field: each one is an error at its key (recorded, so the
    rest of the file is still read; the field itself is not)."""
    if schema >= 3:
        return
    for key in SCHEMA3_TOP_FIELDS:
        if key in top:
            r.log.add(r.error(_needs3(key, schema), r.loc(top[key][0], (key,))))


def require_schema3_param(r, name: str, key: str, key_node: yaml.Node) -> None:
    """A parameter field of schema 3 (`uncertain`, `bounds`) in an earlier schema's file: an error at that key."""
    if r.schema < 3:
        raise r.error(_needs3(key, r.schema), r.loc(key_node, ("parameters", name, key)))


def number(r, node: yaml.Node, path: tuple[str, ...], what: str, allow_inf: bool = False) -> float:
    """A YAML number (not an expression, not a boolean): finite unless ``allow_inf``, never NaN."""
    value = r.scalar(node, path)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        shown = "empty" if value is None else f"`{r.show(str(value))}`"
        raise r.error(f"{what} must be a number (numbers here are plain numbers, not expressions), got {shown}",
                      r.loc(node, path))
    try:
        value = float(value)
    except OverflowError:
        raise r.error("number too large; write it in floating point, e.g. `1.0e+30`", r.loc(node, path)) from None
    if math.isnan(value) or (math.isinf(value) and not allow_inf):
        raise r.error(f"{what} must be a finite number, got {value}", r.loc(node, path))
    return value


def _numbers(r, node: yaml.Node, path: tuple[str, ...], what: str, count: int | None, shape: str,
             allow_inf: bool = False) -> tuple[tuple[float, ...], tuple]:
    """A list of numbers (exactly ``count`` of them, or at least one): the values and where each is."""
    if not isinstance(node, yaml.SequenceNode):
        raise r.error(f"{what} must be a list `{shape}`, got {_kind(r, node)}", r.loc(node, path))
    if count is not None and len(node.value) != count:
        raise r.error(f"{what} must be a list `{shape}` of {count} numbers, got {len(node.value)}", r.loc(node, path))
    if not node.value:
        raise r.error(f"{what} is empty; list at least one value, e.g. `[1.0, 2.0]`", r.loc(node, path))
    values = tuple(number(r, item, path + (str(i),), f"item {i + 1} of {what}", allow_inf)
                   for i, item in enumerate(node.value))
    return values, tuple(r.loc(item, path + (str(i),)) for i, item in enumerate(node.value))


def _kind(r, node: yaml.Node) -> str:
    if isinstance(node, yaml.MappingNode):
        return "a mapping"
    if isinstance(node, yaml.SequenceNode):
        return "a list"
    return f"`{r.show(node.value)}`"


def distribution(r, node: yaml.Node, param: str) -> Distribution:
    """``uncertain: {KIND: [numbers]}``: exactly one kind, its numbers, and what each kind requires of them."""
    path = ("parameters", param, "uncertain")
    if not isinstance(node, yaml.MappingNode):
        raise r.error(f"`uncertain` of `{r.show(param)}` must be a mapping with one distribution: {_KINDS}; got "
                      f"{_kind(r, node)}", r.loc(node, path))
    items = r.mapping(node, path, dict.fromkeys(DISTRIBUTIONS, False), f"`uncertain` of `{r.show(param)}`")
    if len(items) != 1:
        if not items and node.value:  # every key was refused, each with its own error
            raise Unresolved
        raise r.error(f"`uncertain` of `{r.show(param)}` takes exactly one distribution, got {len(items)}; write one "
                      f"of {_KINDS}", r.loc(node, path))
    kind, _, args_node = items[0]
    shape, count = DISTRIBUTIONS[kind]
    what = f"`{kind}` of `{r.show(param)}`"
    args, arg_locs = _numbers(r, args_node, path + (kind,), what, count, shape)
    return Distribution(kind=kind, args=args, loc=r.loc(args_node, path + (kind,)), arg_locs=arg_locs)


def param_bounds(r, node: yaml.Node, param: str):
    """A parameter's physical domain ``bounds: [lo, hi]`` (numbers; `.inf` for no bound): ``(lo, hi), loc``."""
    path = ("parameters", param, "bounds")
    (lo, hi), _ = _numbers(r, node, path, f"`bounds` of `{r.show(param)}`", 2, "[lower, upper]", allow_inf=True)
    return (lo, hi), r.loc(node, path)


def scenarios(r, node: yaml.Node) -> tuple[tuple[Scenario, ...], object]:
    """``scenarios: [{name: value, ...}, ...]``: a non-empty list of mappings of numbers; each read on its own."""
    loc = r.loc(node, ("scenarios",))
    if not isinstance(node, yaml.SequenceNode):
        raise r.error(f"`scenarios` must be a list of scenarios, e.g. `[{{k: 1.5}}, {{k: 2.5}}]`, got "
                      f"{_kind(r, node)}", loc)
    if not node.value:
        raise r.error("`scenarios` is empty; list at least one scenario, e.g. `[{k: 1.5}]`, or remove the field "
                      "(the robust plan then draws `robust.samples` scenarios)", loc)
    read = [r.log.attempt(_scenario, r, i, item) for i, item in enumerate(node.value)]
    if any(s is None for s in read):
        raise Unresolved
    return tuple(read), loc


def _scenario(r, i: int, node: yaml.Node) -> Scenario:
    path = ("scenarios", str(i + 1))
    items = r.mapping(node, path, None, f"scenario {i + 1} (parameter: value)")
    values = tuple((key, r.log.attempt(number, r, vn, path + (key,), f"`{r.show(key)}` in scenario {i + 1}"),
                    r.loc(kn, path + (key,))) for key, kn, vn in items)
    if any(v is None for _, v, _ in values):
        raise Unresolved
    return Scenario(loc=r.loc(node, path), values=values)


def robust(r, node: yaml.Node) -> Robust:
    """``robust: {objective: mean | worst | {cvar: alpha}, samples: N, seed: S}``."""
    path = ("robust",)
    if isinstance(node, yaml.ScalarNode):  # `robust: mean`, the usual slip
        raise r.error(f"`robust` is a mapping: write `robust: {{objective: {r.show(node.value)}}}` (objective `mean`, "
                      "`worst` or `{cvar: alpha}`)", r.loc(node, path))
    f = {k: (kn, vn) for k, kn, vn in r.mapping(node, path, ROBUST_FIELDS, "`robust`")}
    loc = r.loc(node, path)
    if "objective" not in f:
        raise r.error("`robust` needs `objective:` (`mean`, `worst` or `{cvar: alpha}`), e.g. "
                      "`robust: {objective: mean}`", loc)
    objective, alpha, alpha_loc = r.log.attempt(_objective, r, f["objective"][1]) or (None, None, None)
    samples = r.log.attempt(_whole, r, f["samples"][1], "samples") if "samples" in f else DEFAULT_SAMPLES
    seed = r.log.attempt(_whole, r, f["seed"][1], "seed") if "seed" in f else DEFAULT_SEED
    if objective is None or samples is None or seed is None:
        raise Unresolved
    where = {k: r.loc(f[k][1], path + (k,)) for k in ("samples", "seed") if k in f}
    return Robust(loc=loc, objective=objective, alpha=alpha, alpha_loc=alpha_loc, samples=samples, seed=seed,
                  samples_loc=where.get("samples"), seed_loc=where.get("seed"))


def _objective(r, node: yaml.Node):
    """``mean`` | ``worst`` | ``{cvar: alpha}`` with 0 < alpha < 1: ``(objective, alpha, alpha's location)``."""
    path = ("robust", "objective")
    if isinstance(node, yaml.MappingNode):
        items = r.mapping(node, path, {"cvar": True}, "`objective` (`{cvar: alpha}`)")
        alpha_node = items[0][2]
        apath = path + ("cvar",)
        return "cvar", number(r, alpha_node, apath, "cvar's alpha"), r.loc(alpha_node, apath)
    value = r.scalar(node, path)
    if value == "cvar":
        raise r.error("`cvar` needs its alpha: write `objective: {cvar: 0.9}` (0 < alpha < 1)", r.loc(node, path))
    if value not in ROBUST_OBJECTIVES:
        raise r.error(f"`objective` must be `mean`, `worst` or `{{cvar: alpha}}`, got `{r.show(str(value))}`",
                      r.loc(node, path))
    return value, None, None


def _whole(r, node: yaml.Node, key: str) -> int:
    """A whole number (its range is checked with the other values, in :mod:`.checks_schema3`)."""
    value = r.scalar(node, ("robust", key))
    if isinstance(value, bool) or not isinstance(value, int):
        why = {"samples": "the number of scenarios drawn for the robust plan", "seed": "the seed they are drawn with"}
        raise r.error(f"`{key}` ({why[key]}) must be a whole number, got `{r.show(str(value))}`",
                      r.loc(node, ("robust", key)))
    return value


def noise(r, node: yaml.Node) -> Noise:
    """``noise: {process: {STATE: sigma}, observation: {STATE: std}}``, levels >= 0; each entry read on its own."""
    path = ("noise",)
    loc = r.loc(node, path)
    f = {k: v for k, _, v in r.mapping(node, path, NOISE_FIELDS, "`noise`")}
    if not f and not (isinstance(node, yaml.MappingNode) and node.value):
        raise r.error("`noise` is empty; give `process: {STATE: sigma}` and/or `observation: {STATE: std}`, or "
                      "remove the field", loc)
    parts = {k: r.log.attempt(_levels, r, k, v) for k, v in f.items()}
    if any(v is None for v in parts.values()) or not parts:
        raise Unresolved
    return Noise(loc=loc, **parts)


def _levels(r, part: str, node: yaml.Node) -> tuple[NoiseLevel, ...]:
    path = ("noise", part)
    meaning = {"process": "sigma, the diffusion of dx = f dt + sigma dW", "observation": "std of additive noise"}
    items = r.mapping(node, path, None, f"`noise.{part}` (state: {meaning[part]})")
    if not items:
        raise r.error(f"`noise.{part}` is empty; list states with their levels, e.g. `{{x: 0.05}}`, or remove it",
                      r.loc(node, path))
    levels = tuple(r.log.attempt(_level, r, part, key, kn, vn) for key, kn, vn in items)
    if any(v is None for v in levels):
        raise Unresolved
    return levels


def _level(r, part: str, key: str, kn: yaml.Node, vn: yaml.Node) -> NoiseLevel:
    path = ("noise", part, key)
    level = number(r, vn, path, f"the {part} noise of `{r.show(key)}`")
    return NoiseLevel(state=key, level=level, loc=r.loc(kn, path), value_loc=r.loc(vn, path), part=part)
