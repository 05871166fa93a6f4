"""Pass 1, parse: YAML text → :class:`ProblemSpec`, keeping the source position of every field.

Only the YAML *structure* and scalar types are checked here; expressions stay text until the symbolic pass.
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

import yaml

from . import parse_schema2, parse_schema3
from .errors import ErrorLog, Location, SpecError, Unresolved
from .schema import SUPPORTED_SCHEMAS, Expr, Named, Parameter, ProblemSpec, Variable

__all__ = ["parse_spec", "parse_file"]

MAX_SPEC_BYTES = 1_000_000

TOP_FIELDS = {
    "schema": True, "name": True, "title": True, "description": True, "source": False, "parameters": False,
    "definitions": False, "states": True, "controls": True, "dynamics": True, "cost": True, "horizon": True,
    "reference": False, "path_constraints": False, "scenarios": False, "robust": False, "noise": False,
}
PARAM_FIELDS = {"value": True, "description": False, "units": False, "learnable": False, "guess": False,
                "uncertain": False, "bounds": False}
STATE_FIELDS = {"initial": True, "final": False, "bounds": False, "description": False, "units": False}
CONTROL_FIELDS = {"bounds": False, "description": False, "units": False}
COST_FIELDS = {"sense": True, "running": True, "terminal": False}
REFERENCE_FIELDS = {"published": False, "target": False, "note": False}
SENSES = ("minimize", "maximize")
_CORE_TAGS = frozenset(f"tag:yaml.org,2002:{t}" for t in ("str", "int", "float", "bool", "null", "map", "seq"))


class _Refused(yaml.MarkedYAMLError):
    """Valid YAML that specs do not accept (aliases, tags); the message is the problem itself."""


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses aliases and tags while composing.

    An alias shares one node between several fields, so every error about it would point at the anchor, and aliases
    nest exponentially (billion laughs); tags such as ``!!python/object`` mean nothing in a spec and are never
    constructed, so they are rejected rather than silently ignored.
    """

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            raise _Refused(None, None, "YAML aliases (`*name`) are not supported; write the value out in full",
                           event.start_mark)
        tag = getattr(event, "tag", None)
        if tag is not None and tag not in _CORE_TAGS:
            shown = _show(tag.replace("tag:yaml.org,2002:", "!!"), 60)
            raise _Refused(None, None, f"YAML tags such as `{shown}` are not supported; remove the tag",
                           event.start_mark)
        return super().compose_node(parent, index)


class _Reader:
    """Walks composed YAML nodes with their marks, producing SpecErrors that point into the file."""

    def __init__(self, file: str, text: str):
        self.file = file
        self.lines = tuple(text.splitlines())
        self._loader = yaml.SafeLoader("")
        self.log = ErrorLog()
        self.schema = 1  # the file's schema, once read: parameters check their schema 3 fields against it

    def loc(self, node: yaml.Node, path: tuple[str, ...]) -> Location:
        return Location(self.file, node.start_mark.line + 1, node.start_mark.column + 1, path)

    @staticmethod
    def show(text: str, limit: int = 40) -> str:
        return _show(text, limit)

    def error(self, message: str, loc: Location) -> SpecError:
        line = self.lines[loc.line - 1] if 0 < loc.line <= len(self.lines) else None
        return SpecError(message, loc, line)

    def mapping(self, node: yaml.Node, path: tuple[str, ...], fields: dict[str, bool] | None, what: str,
                partial: bool = False):
        """Check a mapping node; return [(key, key_node, value_node)] in file order.

        A bad key (not a name, a duplicate, an unknown field) is recorded in the log and left out, so the other
        fields are still read; a missing required field raises (the caller needs it), or with ``partial`` is
        recorded too (the spec's top level, whose sections are read independently).
        """
        if not isinstance(node, yaml.MappingNode):
            raise self.error(f"expected a mapping ({what}), got {_kind(node)}", self.loc(node, path))
        items, seen = [], {}
        for key_node, value_node in node.value:
            problem = self._bad_key(key_node, path, fields, what, seen)
            if problem is not None:
                self.log.add(problem)
                continue
            seen[key_node.value] = key_node.start_mark.line + 1
            items.append((key_node.value, key_node, value_node))
        missing = [self.error(f"missing required field `{f}` in {what}; add `{f}: ...`", self.loc(node, path))
                   for f, required in (fields or {}).items() if required and f not in seen]
        if missing and not partial:
            raise missing[0]
        for problem in missing:
            self.log.add(problem)
        return items

    def _bad_key(self, key_node: yaml.Node, path: tuple[str, ...], fields, what: str, seen: dict) -> SpecError | None:
        """Why a mapping key is refused (not a plain name, a duplicate, an unknown field), or None."""
        if not isinstance(key_node, yaml.ScalarNode) or key_node.tag != "tag:yaml.org,2002:str":
            return self.error(f"keys must be plain names, got {_kind(key_node)}; write `name: ...`",
                              self.loc(key_node, path))
        key = key_node.value
        if key in seen:
            return self.error(f"duplicate key `{_show(key)}` (first at line {seen[key]}); remove one of them",
                              self.loc(key_node, path + (key,)))
        if fields is not None and key not in fields:
            allowed = ", ".join(fields)
            return self.error(f"unknown field `{_show(key)}` in {what}{_did_you_mean(key, fields)}; allowed fields: "
                              f"{allowed}", self.loc(key_node, path + (key,)))
        return None

    def bounds(self, node: yaml.Node, path: tuple[str, ...]) -> tuple[Expr, Expr, Location]:
        """``bounds: [lower, upper]`` under ``path``: the two expressions and where the list is."""
        loc = self.loc(node, path + ("bounds",))
        if not isinstance(node, yaml.SequenceNode) or len(node.value) != 2:
            got = _kind(node) if not isinstance(node, yaml.SequenceNode) else f"{len(node.value)} items"
            raise self.error(f"`bounds` must be a list `[lower, upper]`, got {got}", loc)
        return (self.expr(node.value[0], path + ("bounds", "lower")),
                self.expr(node.value[1], path + ("bounds", "upper")), loc)

    def scalar(self, node: yaml.Node, path: tuple[str, ...]) -> Any:
        if not isinstance(node, yaml.ScalarNode):
            raise self.error(f"expected a single value, got {_kind(node)}", self.loc(node, path))
        try:
            return self._loader.construct_object(node)
        except (yaml.YAMLError, ValueError) as exc:  # ValueError: e.g. an integer too long, a date like 2024-13-45
            raise self.error(f"cannot read this value ({_first_line(exc)})", self.loc(node, path)) from None

    def text(self, node: yaml.Node, path: tuple[str, ...], what: str) -> str:
        value = self.scalar(node, path)
        if not isinstance(value, str):
            raise self.error(f"expected text for {what}, got {type(value).__name__} `{value}`", self.loc(node, path))
        self.valid_unicode(value, node, path)
        return value

    def valid_unicode(self, value: str, node: yaml.Node, path: tuple[str, ...]) -> None:
        """Text must be encodable: a lone surrogate (from an escape such as ``\\ud800``) breaks the generated module."""
        try:
            value.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise self.error(f"text is not valid Unicode: it contains a lone surrogate U+{ord(value[exc.start]):04X}; "
                             "remove it or write the whole character", self.loc(node, path)) from None

    def boolean(self, node: yaml.Node, path: tuple[str, ...]) -> bool:
        value = self.scalar(node, path)
        if not isinstance(value, bool):
            raise self.error(f"expected true or false, got `{_show(str(value))}`", self.loc(node, path))
        return value

    def expr(self, node: yaml.Node, path: tuple[str, ...]) -> Expr:
        """An expression or number; YAML numbers stay numbers, anything else becomes expression text."""
        loc = self.loc(node, path)
        value = self.scalar(node, path)
        if isinstance(value, bool) or value is None:
            shown = "empty" if value is None else str(value).lower()
            raise self.error(f"expected a number or an expression, got {shown}", loc)
        if isinstance(value, (int, float)):
            try:
                return Expr(text=node.value, loc=loc, number=float(value))
            except OverflowError:
                raise self.error("number too large; write it in floating point, e.g. `1.0e+30`", loc) from None
        if not isinstance(value, str):
            raise self.error(f"expected a number or an expression, got {type(value).__name__}", loc)
        single_line = node.start_mark.line == node.end_mark.line
        quote = 1 if node.style in ("'", '"') else 0
        # Columns map onto the file only when the text is the scalar verbatim (no escapes, no folding).
        offset_ok = single_line and node.style in (None, "'", '"') and "\\" not in value and "''" not in value
        return Expr(text=value, loc=loc, offset_ok=offset_ok, quote=quote)


def _kind(node: yaml.Node) -> str:
    if isinstance(node, yaml.MappingNode):
        return "a mapping"
    if isinstance(node, yaml.SequenceNode):
        return "a list"
    return f"`{_show(node.value)}`"


def _show(text: str, limit: int = 40) -> str:
    """Quote user text for a message: printable, one line, bounded."""
    text = "".join(ch if ch.isprintable() else "?" for ch in str(text))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _first_line(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _did_you_mean(key: str, options) -> str:
    import difflib

    close = difflib.get_close_matches(key, list(options), n=1)
    return f" (did you mean `{close[0]}`?)" if close else ""


def parse_spec(text: str, file: str = "<spec>") -> ProblemSpec:
    """Parse spec text. Raises :class:`SpecError` (or :class:`SpecErrors`, a subclass) with every independent
    problem found: the sections, and the entries within them, are read independently; a YAML error or a bad
    `schema:` stops the pass (nothing after it can be read reliably)."""
    r = _Reader(file, text)
    spec = None
    try:
        spec = _read_spec(r, text, file)
    except SpecError as exc:  # a fatal problem: what was logged before it comes first
        r.log.add(exc)
    r.log.stop()
    return spec


def _read_spec(r: _Reader, text: str, file: str) -> ProblemSpec | None:
    root = _load_yaml(r, text, file)
    top = {k: (kn, vn) for k, kn, vn in r.mapping(root, (), TOP_FIELDS, "the spec", partial=True)}
    if "schema" not in top:
        return None
    schema = _schema(r, top)
    readers = {
        "name": lambda n: r.text(n, ("name",), "the system name"),
        "title": lambda n: r.text(n, ("title",), "the title"),
        "description": lambda n: r.text(n, ("description",), "the description"),
        "source": lambda n: r.text(n, ("source",), "the source"),
        "parameters": lambda n: _parameters(r, n),
        "definitions": lambda n: _named(r, n, "definitions", "`definitions`"),
        "states": lambda n: _variables(r, n, "states", STATE_FIELDS, "state"),
        "controls": lambda n: _variables(r, n, "controls", CONTROL_FIELDS, "control"),
        "dynamics": lambda n: _named(r, n, "dynamics", "`dynamics` (one equation per state)"),
        "cost": lambda n: _cost(r, n),
        "horizon": lambda n: _horizon(r, n),
        "path_constraints": lambda n: parse_schema2.path_constraints(r, n),
        "reference": lambda n: _reference(r, n),
    }
    if schema >= 3:  # in an earlier schema's file these fields are errors (require_schema3), and are not read
        readers.update(scenarios=lambda n: parse_schema3.scenarios(r, n), robust=lambda n: parse_schema3.robust(r, n),
                       noise=lambda n: parse_schema3.noise(r, n))
    # Each section on its own: an error in one is recorded and the others are still read.
    f = {key: r.log.attempt(read, top[key][1]) for key, read in readers.items() if key in top}
    if r.log.errors:
        return None
    free_horizon, horizon = f["horizon"]
    return ProblemSpec(
        file=file, lines=r.lines, sha256=hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest(),
        schema=schema, name=f["name"], name_loc=r.loc(top["name"][1], ("name",)), title=f["title"],
        description=f["description"], source=f.get("source", ""), parameters=tuple(f.get("parameters", ())),
        definitions=tuple(f.get("definitions", ())), states=tuple(f["states"]), controls=tuple(f["controls"]),
        dynamics=tuple(f["dynamics"]), dynamics_loc=r.loc(top["dynamics"][1], ("dynamics",)), sense=f["cost"][0],
        running=f["cost"][1], terminal=f["cost"][2], horizon=horizon, reference=tuple(f.get("reference", ())),
        free_horizon=free_horizon, path_constraints=f.get("path_constraints", ()),
        scenarios=f["scenarios"][0] if "scenarios" in f else (), scenarios_loc=f["scenarios"][1] if "scenarios" in f
        else None, robust=f.get("robust"), noise=f.get("noise"),
    )


def _named(r: _Reader, node: yaml.Node, section: str, what: str) -> list[Named]:
    """A mapping of name → expression (`definitions`, `dynamics`); each entry read on its own."""
    return [r.log.attempt(_named_entry, r, section, key, kn, vn) for key, kn, vn in r.mapping(node, (section,), None,
                                                                                                 what)]


def _named_entry(r: _Reader, section: str, key: str, kn: yaml.Node, vn: yaml.Node) -> Named:
    return Named(key, r.loc(kn, (section, key)), r.expr(vn, (section, key)))


def _horizon(r: _Reader, node: yaml.Node):
    """``(free_horizon, horizon)``: a fixed horizon's expression, or a free final time and its guess."""
    if isinstance(node, yaml.MappingNode):
        free = parse_schema2.free_horizon(r, node)
        return free, free.guess
    return None, r.expr(node, ("horizon",))


def _load_yaml(r: _Reader, text: str, file: str) -> yaml.Node:
    """The document's root node, composed by the safe loader (nothing constructed, no tags); a YAML error, an
    oversized or empty spec as a :class:`SpecError` at its line and column."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_SPEC_BYTES:
        raise r.error(f"spec is larger than {MAX_SPEC_BYTES} bytes", Location(file, 1, 1))
    try:
        loader = _Loader(text)
        try:
            root = loader.get_single_node()
        finally:
            loader.dispose()
    except _Refused as exc:
        raise r.error(exc.problem, Location(file, exc.problem_mark.line + 1, exc.problem_mark.column + 1)) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        what = ", ".join(m for m in (exc.context, exc.problem) if m)
        hint = "indent with spaces, not tabs" if "'\\t'" in what else "check indentation and quoting"
        raise r.error(f"invalid YAML: {what}; {hint}", Location(file, line, col)) from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow, at a character offset
        line = text.count("\n", 0, exc.position) + 1
        col = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
        raise r.error(f"invalid YAML: {_first_line(exc)}; remove it (in double-quoted text, write an escape such as "
                      "`\\x07`)", Location(file, line, col)) from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:
        raise r.error(f"invalid YAML: {_first_line(exc)}", Location(file, 1, 1)) from None
    if root is None:
        raise r.error("the spec is empty; start with `schema: 1`", Location(file, 1, 1))
    return root


def _schema(r: _Reader, top: dict) -> int:
    """The schema version, one this compiler reads, and no field of a later schema in an earlier one."""
    schema_node = top["schema"][1]
    schema = r.scalar(schema_node, ("schema",))
    if isinstance(schema, bool) or not isinstance(schema, int) or schema not in SUPPORTED_SCHEMAS:
        got = f"text `{_show(schema)}`" if isinstance(schema, str) else f"`{_show(str(schema))}`"
        names = [f"`schema: {v}`" for v in SUPPORTED_SCHEMAS]
        versions = ", ".join(names[:-1]) + " or " + names[-1] if len(names) > 1 else names[0]
        raise r.error(f"unsupported schema {got}; this compiler reads {versions} (a number)",
                      r.loc(schema_node, ("schema",)))
    parse_schema2.require_schema2(r, schema, top)
    r.schema = schema
    parse_schema3.require_schema3(r, schema, top)
    return schema


def _parameters(r: _Reader, node: yaml.Node) -> list[Parameter]:
    """The `parameters` section; each parameter read on its own."""
    return [r.log.attempt(_parameter, r, key, kn, vn) for key, kn, vn in r.mapping(node, ("parameters",), None,
                                                                                   "`parameters`")]


def _parameter(r: _Reader, key: str, kn: yaml.Node, vn: yaml.Node) -> Parameter:
    path = ("parameters", key)
    if isinstance(vn, yaml.ScalarNode):  # shorthand `k: 0.5`
        return Parameter(key, r.loc(kn, path), r.expr(vn, path + ("value",)))
    keys = r.mapping(vn, path, PARAM_FIELDS, f"parameter `{_show(key)}`")
    f = {k: v for k, _, v in keys}
    for k, k_node, _ in keys:
        if k in parse_schema3.SCHEMA3_PARAM_FIELDS:
            r.log.attempt(parse_schema3.require_schema3_param, r, key, k, k_node)
    schema3 = _parameter_schema3(r, key, f) if r.schema >= 3 else {}
    learnable = r.boolean(f["learnable"], path + ("learnable",)) if "learnable" in f else False
    guess = r.expr(f["guess"], path + ("guess",)) if "guess" in f else None
    if learnable and guess is None:
        raise r.error(f"learnable parameter `{key}` needs a `guess:` (the starting value for system "
                      "identification)", r.loc(vn, path))
    if guess is not None and not learnable:
        raise r.error("`guess` is only used with `learnable: true`; add `learnable: true` or remove `guess`",
                      r.loc(f["guess"], path + ("guess",)))
    return Parameter(
        name=key, loc=r.loc(kn, path), value=r.expr(f["value"], path + ("value",)),
        description=(r.text(f["description"], path + ("description",), "a description")
                     if "description" in f else ""),
        units=r.text(f["units"], path + ("units",), "units") if "units" in f else "",
        learnable=learnable, guess=guess, **schema3,
    )


def _parameter_schema3(r: _Reader, key: str, f: dict) -> dict:
    """A schema 3 parameter's `uncertain` and `bounds`, as keyword arguments of :class:`Parameter`; both are read
    (and their errors recorded) before either stops the parameter."""
    uncertain = r.log.attempt(parse_schema3.distribution, r, f["uncertain"], key) if "uncertain" in f else None
    bounds = r.log.attempt(parse_schema3.param_bounds, r, f["bounds"], key) if "bounds" in f else None
    if ("uncertain" in f and uncertain is None) or ("bounds" in f and bounds is None):
        raise Unresolved  # recorded above
    (lo_hi, loc) = bounds if bounds else (None, None)
    return {"uncertain": uncertain, "bounds": lo_hi, "bounds_loc": loc}


def _cost(r: _Reader, node: yaml.Node) -> tuple:
    """``(sense, running, terminal)`` of the `cost` section (terminal None when absent); each read on its own."""
    cost = {k: v for k, _, v in r.mapping(node, ("cost",), COST_FIELDS, "`cost`")}
    sense = r.log.attempt(_sense, r, cost["sense"])
    running = r.log.attempt(r.expr, cost["running"], ("cost", "running"))
    terminal = r.log.attempt(r.expr, cost["terminal"], ("cost", "terminal")) if "terminal" in cost else None
    return sense, running, terminal


def _sense(r: _Reader, node: yaml.Node) -> str:
    sense = r.scalar(node, ("cost", "sense"))
    if sense not in SENSES:
        raise r.error(f"`sense` must be `minimize` or `maximize`, got `{_show(str(sense))}`",
                      r.loc(node, ("cost", "sense")))
    return sense


def _reference(r: _Reader, node: yaml.Node) -> list[tuple[str, object]]:
    """The `reference` section's ``(key, value)`` pairs: a text note and finite numbers (minimisation form)."""
    return [r.log.attempt(_reference_entry, r, key, vn)
            for key, _, vn in r.mapping(node, ("reference",), REFERENCE_FIELDS, "`reference`")]


def _reference_entry(r: _Reader, key: str, vn: yaml.Node) -> tuple[str, object]:
    value = r.scalar(vn, ("reference", key))
    if key == "note":
        if not isinstance(value, str):
            raise r.error("`note` must be text", r.loc(vn, ("reference", key)))
        r.valid_unicode(value, vn, ("reference", key))
        return key, value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise r.error(f"`{key}` must be a finite number (minimisation form), got `{_show(str(value))}`",
                      r.loc(vn, ("reference", key)))
    return key, float(value)


def _variables(r: _Reader, node: yaml.Node, section: str, fields: dict[str, bool], kind: str) -> list[Variable]:
    """The `states` or `controls` section; each variable read on its own."""
    items = r.mapping(node, (section,), None, f"`{section}`")
    if not items:
        raise r.error(f"`{section}` is empty; declare at least one {kind}", r.loc(node, (section,)))
    return [r.log.attempt(_variable, r, key, kn, vn, section, fields, kind) for key, kn, vn in items]


def _variable(r: _Reader, key: str, kn: yaml.Node, vn: yaml.Node, section: str, fields: dict[str, bool],
              kind: str) -> Variable:
    path = (section, key)
    f = {k: v for k, _, v in r.mapping(vn, path, fields, f"{kind} `{_show(key)}`")}
    lower = upper = bounds_loc = None
    if "bounds" in f:
        lower, upper, bounds_loc = r.bounds(f["bounds"], path)
    return Variable(
        name=key, loc=r.loc(kn, path), kind=kind,
        initial=r.expr(f["initial"], path + ("initial",)) if "initial" in f else None,
        final=r.expr(f["final"], path + ("final",)) if "final" in f else None,
        lower=lower, upper=upper, bounds_loc=bounds_loc,
        description=(r.text(f["description"], path + ("description",), "a description")
                     if "description" in f else ""),
        units=r.text(f["units"], path + ("units",), "units") if "units" in f else "",
    )


def parse_file(path: str, display: str | None = None) -> ProblemSpec:
    """Read and parse a spec file; ``display`` is the path shown in messages."""
    display = display or path
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_SPEC_BYTES + 1)
    except OSError as exc:
        raise SpecError(f"cannot read file: {exc.strerror}", Location(display, 1, 1)) from None
    return parse_spec(decode_spec(raw, display), display)


def decode_spec(raw: bytes, display: str) -> str:
    """The spec's bytes as text; a non-UTF-8 byte is reported at its own line and column."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = raw.rfind(b"\n", 0, exc.start) + 1
        line = raw.count(b"\n", 0, exc.start) + 1
        column = len(raw[line_start : exc.start].decode("utf-8", "replace")) + 1
        raise SpecError(f"file is not UTF-8 text: byte 0x{raw[exc.start]:02x} at offset {exc.start}; save the file "
                        "as UTF-8", Location(display, line, column)) from None
