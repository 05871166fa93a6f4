"""A frozen dataclass config is a command's interface: its fields, types, defaults and docstring make the flags.

One config per command serves the Python API, the CLI and the sweep as it is; nothing restates its fields::

    add_arguments(parser, SolveConfig, spelled={"intervals": ("--intervals", "--controls")})
    config = from_args(SolveConfig, parser.parse_args(argv))  # ValueError: a usage error (usage_message)
    config = build(SolveConfig, {"transcription": "trapezoidal", "intervals": 20})  # the sweep's KEY=VALUE

Each field becomes ``--field-name``, typed from its annotation: ``bool`` -> ``--x``/``--no-x``; ``int``, ``float``,
``str`` (or None) -> one value; ``tuple[X, ...]`` -> one or more; a ``Literal`` or an ``Enum`` -> its choices;
anything else (a mapping, a nested config, an object) -> one JSON value. Its help is the field's entry in the
docstring's ``Attributes:`` section. ``--set KEY=VALUE`` (repeatable) sets any field, a nested config's field by a
dotted key (``--set fit.epochs=200``); a VALUE is read as JSON when it parses, else as a plain word
(:func:`parse_value`, also the sweep's rule). Flags only pass on what was given, so the defaults live in the config
alone, and so does validation: its ``__post_init__`` raises ``ValueError``, which the commands report as a usage
error (exit 2) naming the flag (:func:`usage_message`). A plain-argparse module rather than a library (tyro): the
commands keep their flag spellings and parsers, and the sweep shares the parsing of values.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import inspect
import json
import numbers
import re
import types
import typing
from typing import Any, Mapping

__all__ = ["FieldError", "add_arguments", "build", "defaults", "field_docs", "flag", "from_args", "parse_value",
           "to_json", "usage_message"]


class FieldError(ValueError):
    """A bad value of ``fields``; the message names them as words (``"intervals must be ..."``), which a command
    respells as its flags (:func:`usage_message`)."""

    def __init__(self, message: str, *fields: str):
        super().__init__(message)
        self.fields = fields


def parse_value(text: str) -> Any:
    """``text`` read as JSON when it parses (``20``, ``1e-6``, ``true``, ``null``, ``[32,32]``, ``{"tol":1e-6}``),
    else the text itself (a plain word such as ``trapezoidal``)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def field_docs(cls: type) -> dict[str, str]:
    """Each field's entry in the docstring's ``Attributes:`` section (``a, b: text`` documents both), one line."""
    docs, names, indent, section = {}, [], None, False
    for line in inspect.cleandoc(cls.__doc__ or "").splitlines():
        stripped, depth = line.strip(), len(line) - len(line.lstrip())
        if re.fullmatch(r"[A-Z][\w ]*:", stripped) and (indent is None or depth < indent):
            section, indent = stripped == "Attributes:", None  # "Raises:" and the like end the attributes
            continue
        entry = re.fullmatch(r"([\w, ]+):\s(.*)", stripped) if section and indent in (None, depth) else None
        if entry and all(n.strip().isidentifier() for n in entry[1].split(",")):
            names, indent = [n.strip() for n in entry[1].split(",")], depth
            docs.update(dict.fromkeys(names, entry[2].strip()))
        elif section and stripped and names and depth > indent:
            for n in names:
                docs[n] += " " + stripped
    return docs


def _options(hint: Any) -> tuple[Any, bool]:
    """``(the hint without None, whether None is allowed)``."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args:
        rest = tuple(a for a in args if a is not type(None))
        return (rest[0] if len(rest) == 1 else typing.Union[rest]), True
    return hint, False


def flag(name: str, spelled: Mapping[str, tuple[str, ...]] | None = None) -> str:
    """The flag of field ``name`` (``x0_std`` -> ``--x0-std``), or its first spelling in ``spelled``; a nested
    field (``fit.epochs``) is set by ``--set fit.epochs=...``."""
    if spelled and name in spelled:
        return spelled[name][0]
    return f"--set {name}" if "." in name else "--" + name.replace("_", "-")


def add_arguments(parser: argparse.ArgumentParser, cls: type, *, spelled: Mapping[str, tuple[str, ...]] | None = None,
                  choices: Mapping[str, list] | None = None, metavars: Mapping[str, str] | None = None,
                  skip: tuple[str, ...] = ()) -> None:
    """One flag per field of ``cls`` (module docstring) and ``--set KEY=VALUE``.

    Args:
        spelled: a field's flag spellings where they are not ``--field-name`` (kept for old command lines).
        choices: a field's choices where its type does not say them (e.g. names from a registry).
        metavars: a field's metavar in the usage line.
        skip: fields with no flag of their own (still settable by ``--set``).
    """
    docs, hints = field_docs(cls), typing.get_type_hints(cls)
    spelled, choices, metavars = spelled or {}, choices or {}, metavars or {}
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init:
            continue
        kwargs = {"dest": f.name, "default": argparse.SUPPRESS, **_kind(hints[f.name])}
        if f.name in choices:
            kwargs["choices"] = list(choices[f.name])
            kwargs.pop("metavar", None)  # the usage line shows the choices
        if f.name in metavars:
            kwargs["metavar"] = metavars[f.name]
        kwargs["help"] = _help(docs.get(f.name, ""), f)
        parser.add_argument(*spelled.get(f.name, (flag(f.name),)), **kwargs)
    parser.add_argument("--set", dest="set_", action="append", default=[], metavar="KEY=VALUE",
                        help=f"set any field of {cls.__name__}, a nested config's by a dotted KEY; VALUE is JSON or a "
                             "plain word")


def _kind(hint: Any) -> dict[str, Any]:
    """The argparse keywords of a field's annotation (module docstring)."""
    hint, _ = _options(hint)
    args = typing.get_args(hint)
    if hint is bool:
        return {"action": argparse.BooleanOptionalAction}
    if hint in (int, float, str):
        return {"type": hint}
    if typing.get_origin(hint) is tuple and args[1:] == (Ellipsis,) and args[0] in (int, float, str):
        return {"type": args[0], "nargs": "+"}
    if typing.get_origin(hint) is typing.Literal:
        return {"choices": list(args)}
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return {"choices": [m.value for m in hint]}
    return {"type": parse_value, "metavar": "JSON"}


def _help(text: str, f: dataclasses.Field) -> str:
    default = f.default if f.default is not dataclasses.MISSING else None
    text = text.rstrip(".")
    if "default" not in text and isinstance(default, (int, float, str)) and not isinstance(default, bool) \
            and default != "":
        text = f"{text} (default: {default})"
    text = re.sub(r":\w+:`~?(?:[\w.]*\.)?(\w+)`", r"\1", text).replace("``", "")  # reST roles and literals
    return text.replace("%", "%%")  # argparse formats help with %


def from_args(cls: type, args: argparse.Namespace, **given: Any) -> Any:
    """The config of the parsed flags and ``--set`` items (``given`` adds values that have no flag, e.g. a seed).

    Raises:
        ValueError: a malformed ``--set``, an unknown field, or a value the config refuses.
    """
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    values = {name: getattr(args, name) for name in names if hasattr(args, name)}
    for item in getattr(args, "set_", None) or ():
        key, sep, text = (part.strip() for part in item.partition("="))
        if not sep or not key:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        if key.partition(".")[0] not in names:
            raise ValueError(f"--set {item}: unknown field {key!r} of {cls.__name__}; known: {', '.join(names)}")
        values[key] = parse_value(text)
    return build(cls, {**values, **given})


def build(cls: type, values: Mapping[str, Any], base: Any = None) -> Any:
    """``cls(**values)`` with the values read as the annotations say (a list as a tuple, a word as an enum member,
    a mapping as a nested config; ``"a.b"`` keys set a nested config's fields), over ``base``'s values if given.

    Raises:
        ValueError: an unknown field (the known ones are listed) or a value the config refuses.
    """
    hints, names = typing.get_type_hints(cls), [f.name for f in dataclasses.fields(cls) if f.init]
    nested: dict[str, dict[str, Any]] = {}
    flat = {}
    for key, value in values.items():
        head, dot, rest = key.partition(".")
        if head not in names:
            raise ValueError(f"unknown field {key!r} of {cls.__name__}; known: {', '.join(names)}")
        if dot:
            nested.setdefault(head, {})[rest] = value
        else:
            flat[key] = value
    for head, sub in nested.items():
        start = flat.get(head, getattr(base, head) if base is not None else defaults(cls)[head])
        try:
            flat[head] = _nested(hints[head], start, sub)
        except FieldError as exc:  # named by its dotted key, which the commands spell `--set head.name`
            message = str(exc)
            for name in exc.fields:
                message = re.sub(rf"(?<![\w.-]){re.escape(name)}(?![\w-])", f"{head}.{name}", message)
            raise FieldError(message, *(f"{head}.{name}" for name in exc.fields)) from None
    kwargs = {k: _read(hints[k], v) for k, v in flat.items()}
    for k, v in kwargs.items():
        _check_kind(k, hints[k], v)
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except TypeError as exc:  # e.g. a comparison of a word with a number inside the config's own checks
        raise ValueError(f"{cls.__name__}: {exc}") from None


# A scalar annotation: what its values may be, and its words in a message.
_SCALARS = {bool: (bool, "true or false"), int: (numbers.Integral, "an integer"), float: (numbers.Real, "a number"),
            str: (str, "a word")}


def _check_kind(name: str, hint: Any, value: Any) -> None:
    """A value of the annotated kind (a scalar, a list of scalars, one of the config classes, or None where allowed);
    anything else (a stray word, broken JSON) is refused here, naming the field, rather than failing later inside
    the config's own checks or the work."""
    bare, optional = _options(hint)
    args = typing.get_args(bare)
    fits = lambda kind, v: isinstance(v, _SCALARS[kind][0]) and (kind is bool or not isinstance(v, bool))  # noqa: E731
    if value is None and optional:
        return
    if bare in _SCALARS:
        if not fits(bare, value):
            raise FieldError(f"{name} expects {_SCALARS[bare][1]}, got {value!r}", name)
        return
    if typing.get_origin(bare) is tuple and args[1:] == (Ellipsis,) and args[0] in _SCALARS:
        if not (isinstance(value, tuple) and all(fits(args[0], v) for v in value)):
            raise FieldError(f"{name} expects a list, each {_SCALARS[args[0]][1]}, got {value!r}", name)
        return
    declared = args if typing.get_origin(bare) in (typing.Union, types.UnionType) else (bare,)
    if not all(isinstance(c, type) and c.__module__ not in ("builtins", "typing") for c in declared) \
            or isinstance(value, declared):
        return
    words = [w for k in _dataclasses_of(hint) if (w := _word(k))]
    raise FieldError(f"{name} expects a JSON object of its fields{' or one of ' + ', '.join(words) if words else ''}, "
                     f"got {value!r}", name)


def _nested(hint: Any, start: Any, values: dict[str, Any]) -> Any:
    """A nested config with ``values`` set: over ``start`` when it is one, else a new one of the annotated type."""
    if dataclasses.is_dataclass(start) and not isinstance(start, type):
        return build(type(start), values, base=start)
    if isinstance(start, Mapping):
        return {**start, **values}
    kinds = _dataclasses_of(hint)
    if not kinds:
        raise FieldError(f"{hint} has no fields to set by a dotted key", *values)
    return build(kinds[0], values)


def _dataclasses_of(hint: Any) -> list[type]:
    """The config classes a value of ``hint`` may be: the annotated ones (a union's members, first), then their
    concrete subclasses (an abstract base's, e.g. the integrators)."""
    hint, _ = _options(hint)
    declared = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    found, todo = [], [c for c in declared if isinstance(c, type) and c.__module__ != "builtins"]
    while todo:
        c = todo.pop(0)
        if c not in found:
            found.append(c)
            todo += c.__subclasses__()
    return [c for c in found if dataclasses.is_dataclass(c) and not inspect.isabstract(c)]


def _word(cls: type) -> str | None:
    """The name a class answers to in a value: its class attribute ``label`` (solvers, methods) or ``name``
    (adjoints)."""
    fields = {f.name for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else set()
    word = next((getattr(cls, a) for a in ("label", "name") if a not in fields and hasattr(cls, a)), None)
    return word if isinstance(word, str) else None


def _read(hint: Any, value: Any) -> Any:
    """``value`` (from JSON or a flag) as ``hint`` says, where it says more than JSON can: a tuple, an enum member,
    a nested config (a mapping; ``"type"`` picks one class of a union by its word, as does a plain word alone);
    anything else is passed on for the config's own checks."""
    hint, _ = _options(hint)
    if typing.get_origin(hint) is tuple and isinstance(value, list):
        inner = typing.get_args(hint)
        return tuple(_read(inner[0] if inner[1:] == (Ellipsis,) else Any, v) for v in value)
    if isinstance(hint, type) and issubclass(hint, enum.Enum) and not isinstance(value, hint):
        try:
            return hint(value)
        except ValueError:
            return value  # the config names the field and the choices
    kinds = _dataclasses_of(hint)
    named = {_word(k): k for k in kinds if _word(k)}
    if isinstance(value, str) and value in named:
        return named[value]()
    if kinds and isinstance(value, Mapping):
        rest = {k: v for k, v in value.items() if k != "type"}
        return build(named.get(value.get("type"), kinds[0]), rest)
    return value


def to_json(value: Any, skip: tuple[str, ...] = ()) -> Any:
    """``value`` as JSON-native data: a config as the mapping of its fields (``skip`` left out of the outer one;
    ``"type"``: its word, where it has one), tuples as lists, enum members as their values."""
    def native(v, leave=()):
        if isinstance(v, enum.Enum):
            return v.value
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            word = {"type": _word(type(v))} if _word(type(v)) else {}
            return {**word, **{f.name: native(getattr(v, f.name)) for f in dataclasses.fields(v)
                               if f.name not in leave}}
        if isinstance(v, (list, tuple)):
            return [native(x) for x in v]
        if isinstance(v, Mapping):
            return {k: native(x) for k, x in v.items()}
        return v

    return json.loads(json.dumps(native(value, skip)))


def defaults(cls: type) -> dict[str, Any]:
    """Every field's default."""
    return {f.name: f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
            for f in dataclasses.fields(cls) if f.init}


def usage_message(exc: Exception, cls: type, spelled: Mapping[str, tuple[str, ...]] | None = None) -> str:
    """A ``cls`` config's ``ValueError`` in a command's words: the fields it names (a :class:`FieldError`'s, else the
    field that starts it, after a ``Cls: `` or ``Cls(field=value): `` prefix) as their flags, e.g.
    ``intervals must be ...`` -> ``--intervals must be ...``."""
    message, names = str(exc), {f.name for f in dataclasses.fields(cls)}
    fields = getattr(exc, "fields", ())
    if not fields:
        call = re.match(rf"{cls.__name__}\((\w+)=(.*?)\): (.*)", message, re.S)
        if call and call[1] in names:
            message = f"{call[1]} {call[2]}: {call[3]}"
        message = re.sub(rf"^{cls.__name__}: ", "", message)
        lead = re.match(r"[a-z][a-z0-9_]*(?:(?:, | and )[a-z][a-z0-9_]*)*(?=[ :])", message)  # "a and b must ..."
        fields = tuple(n for n in re.split(", | and ", lead[0]) if n in names) if lead else ()
    for name in fields:
        message = re.sub(rf"(?<![\w.-]){re.escape(name)}(?![\w-])", lambda _: flag(name, spelled), message)
    return message
