"""Pass 1, parse, for the fields schema 2 adds: a free final time and path constraints.

Called by :mod:`.parse` with its reader (so positions and messages are the same as for every other field). Only the
YAML structure is checked here; the numbers and expressions are evaluated and checked by the symbolic and check passes
like all others.

    horizon: {free: true, guess: 2.0, bounds: [0.5, 10]}
    path_constraints:
      keep_out: {expression: (x - 1)**2 + (y - 1)**2, bounds: [0.25, .inf], description: stay outside the disc}
"""

from __future__ import annotations

import yaml

from .schema import FreeHorizon, PathConstraint

__all__ = ["FREE_HORIZON_FIELDS", "PATH_FIELDS", "free_horizon", "path_constraints", "require_schema2"]

FREE_HORIZON_FIELDS = {"free": False, "guess": False, "bounds": False}  # required ones get a message of their own
PATH_FIELDS = {"expression": True, "bounds": False, "description": False}


def require_schema2(r, schema: int, top: dict) -> None:
    """A schema 1 file that uses a schema 2 field is refused at that field (it would mean something else, or
    nothing, to a reader of schema 1)."""
    if schema >= 2:
        return
    if "path_constraints" in top:
        key_node = top["path_constraints"][0]
        raise r.error("`path_constraints` needs `schema: 2` (this file declares `schema: 1`); change the `schema:` "
                      "line to `schema: 2`", r.loc(key_node, ("path_constraints",)))
    horizon = top["horizon"][1] if "horizon" in top else None  # a missing horizon is reported on its own
    if isinstance(horizon, yaml.MappingNode):
        raise r.error("a free final time (`horizon: {free: true, ...}`) needs `schema: 2` (this file declares "
                      "`schema: 1`); change the `schema:` line to `schema: 2`, or write the horizon as a number",
                      r.loc(horizon, ("horizon",)))


def free_horizon(r, node: yaml.MappingNode) -> FreeHorizon:
    """``horizon: {free: true, guess: G, bounds: [lo, hi]}``; every field is required."""
    path = ("horizon",)
    f = {k: v for k, _, v in r.mapping(node, path, FREE_HORIZON_FIELDS, "`horizon` (a free final time)")}
    loc = r.loc(node, path)
    if "free" not in f:
        raise r.error("a horizon written as a mapping is a free final time: add `free: true` (or write a fixed "
                      "horizon as a number, `horizon: 10`)", loc)
    if not r.boolean(f["free"], path + ("free",)):
        raise r.error("`free: false` is a fixed final time: write it as a number, e.g. `horizon: 10`",
                      r.loc(f["free"], path + ("free",)))
    if "bounds" not in f:
        raise r.error("a free final time needs `bounds: [lower, upper]`, finite, with 0 < lower <= upper, e.g. "
                      "`bounds: [0.5, 10]`", loc)
    if "guess" not in f:
        raise r.error("a free final time needs `guess:` (the starting final time, between its bounds), e.g. "
                      "`guess: 2.0`", loc)
    lower, upper, bounds_loc = r.bounds(f["bounds"], path)
    return FreeHorizon(loc=loc, guess=r.expr(f["guess"], path + ("guess",)), lower=lower, upper=upper,
                       bounds_loc=bounds_loc)


def path_constraints(r, node: yaml.Node) -> tuple[PathConstraint, ...]:
    """``path_constraints:`` name → ``{expression, bounds, description}``, in file order; each read on its own."""
    items = r.mapping(node, ("path_constraints",), None, "`path_constraints` (name: {expression: ..., bounds: "
                                                          "[lower, upper]})")
    if not items:
        raise r.error("`path_constraints` is empty; declare at least one constraint or remove the field",
                      r.loc(node, ("path_constraints",)))
    return tuple(r.log.attempt(_path_constraint, r, key, kn, vn) for key, kn, vn in items)


def _path_constraint(r, key: str, kn: yaml.Node, vn: yaml.Node) -> PathConstraint:
    path = ("path_constraints", key)
    f = {k: v for k, _, v in r.mapping(vn, path, PATH_FIELDS, f"path constraint `{r.show(key)}`")}
    if "bounds" not in f:
        raise r.error(f"path constraint `{r.show(key)}` needs `bounds: [lower, upper]`; write `.inf` or `-.inf` "
                      "for the side without a bound, e.g. `bounds: [-.inf, 2]`", r.loc(vn, path))
    lower, upper, bounds_loc = r.bounds(f["bounds"], path)
    return PathConstraint(
        name=key, loc=r.loc(kn, path), expr=r.expr(f["expression"], path + ("expression",)),
        lower=lower, upper=upper, bounds_loc=bounds_loc,
        description=(r.text(f["description"], path + ("description",), "a description")
                     if "description" in f else ""),
    )
