"""What a sweep runs: systems x methods x seeds, each task a JSON-ready dict for :func:`.tasks.run`. A method is a
named kind with its settings (the fields of the kind's config), written ``[NAME=]KIND[:KEY=VALUE,...]`` with values
read by :func:`~myriad.runtime.configs.parse_value` (the rule of every command's ``--set KEY=VALUE``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

# One folder for the workers and the commands; `~` expanded per node.
from ..compilation.jax_cache import DEFAULT_CACHE_DIR
from ..configs import FieldError, parse_value
from .kinds import KINDS

__all__ = ["DEFAULT_CACHE_DIR", "Method", "SweepConfig", "parse_method"]


@dataclasses.dataclass(frozen=True)
class Method:
    """A named kind with its settings, checked (and completed with the defaults) when built: ``ValueError`` for an
    unknown kind, an empty name, or settings the kind refuses."""

    name: str
    kind: str
    settings: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown method kind {self.kind!r}; known: {', '.join(KINDS)}")
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"a method needs a non-empty name, got {self.name!r}")
        object.__setattr__(self, "settings", KINDS[self.kind]().check(dict(self.settings)))

    def record(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "settings": self.settings}


def _split(text: str) -> list[str]:
    """``text`` split on the commas outside brackets, braces and double quotes."""
    parts, depth, quoted, start = [], 0, False, 0
    for i, ch in enumerate(text):
        if ch == '"' and (i == 0 or text[i - 1] != "\\"):
            quoted = not quoted
        elif not quoted and ch in "[{":
            depth += 1
        elif not quoted and ch in "]}":
            depth -= 1
        elif not quoted and depth == 0 and ch == ",":
            parts.append(text[start:i])
            start = i + 1
    if depth or quoted:
        raise ValueError(f"unbalanced brackets or quotes in {text!r}")
    return [*parts, text[start:]]


def parse_method(text: str) -> Method:
    """A :class:`Method` from ``[NAME=]KIND[:KEY=VALUE,...]`` (module docstring); the name defaults to the text.
    ``ValueError``: a malformed text, an unknown kind or setting, or a bad value."""
    name, body = None, text.strip()
    eq, colon = body.find("="), body.find(":")
    if eq >= 0 and (colon < 0 or eq < colon):
        name, body = body[:eq].strip(), body[eq + 1:].strip()
    kind, _, rest = body.partition(":")
    settings = {}
    if rest.strip():
        for item in _split(rest):
            key, sep, value = item.partition("=")
            if not sep or not key.strip():
                raise ValueError(f"method {text!r}: expected KEY=VALUE, got {item!r}")
            if key.strip() in settings:
                raise ValueError(f"method {text!r}: {key.strip()!r} given twice")
            settings[key.strip()] = parse_value(value.strip())
    return Method(name=body if name is None else name, kind=kind.strip(), settings=settings)


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Systems (shipped names or spec paths) x methods x seeds.

    Attributes:
        systems: what to run on, in table order.
        methods: :class:`Method` objects or their texts (:func:`parse_method`); names must differ.
        seeds: integers >= 0, each task's seed.
        cache_dir: the JAX persistent compilation cache every worker uses (unless its process already set one);
            None: none. See the README.

    ``ValueError``: a bad method; :class:`~myriad.runtime.configs.FieldError` (naming the field): an empty or
    repeated system, method name or seed.
    """

    systems: tuple[str, ...]
    methods: tuple[Method, ...] = ("solve",)
    seeds: tuple[int, ...] = (0,)
    cache_dir: str | None = DEFAULT_CACHE_DIR

    def __post_init__(self):
        systems = (self.systems,) if isinstance(self.systems, str) else tuple(self.systems)
        methods = tuple(m if isinstance(m, Method) else parse_method(m) for m in self.methods)
        seeds = tuple(self.seeds)
        for what, items in (("systems", systems), ("methods", methods), ("seeds", seeds)):
            if not items:
                raise FieldError(f"{what} needs at least one value", what)
        for what, items in (("systems", systems), ("methods", [m.name for m in methods]), ("seeds", seeds)):
            repeated = sorted({str(x) for x in items if list(items).count(x) > 1})
            if repeated:
                fix = "; give each method its own name, NAME=KIND[:...]" if what == "methods" else ""
                raise FieldError(f"{what} must differ: repeated {', '.join(repeated)}{fix}", what)
        bad = [s for s in seeds if isinstance(s, bool) or not isinstance(s, int) or s < 0]
        if bad:
            raise FieldError(f"seeds must be integers >= 0, got {', '.join(map(str, bad))}", "seeds")
        object.__setattr__(self, "systems", systems)
        object.__setattr__(self, "methods", methods)
        object.__setattr__(self, "seeds", seeds)

    def tasks(self) -> list[dict[str, Any]]:
        """One JSON-ready dict per (system, method, seed), in table order; ``index`` is the position."""
        grid = [(s, m, seed) for s in self.systems for m in self.methods for seed in self.seeds]
        return [{"index": i, "system": s, "method": m.record(), "seed": seed, "cache_dir": self.cache_dir}
                for i, (s, m, seed) in enumerate(grid)]

    def check_systems(self) -> None:
        """Load every system and ask every method's kind whether it can run there (before any work): ``KeyError``
        for a system neither shipped nor a spec file, ``ValueError`` for a method that cannot run on a system,
        ``myriad.compiler.SpecError`` for an invalid spec file."""
        from ..loader import load

        for name in self.systems:
            system = load(name)
            for m in self.methods:
                KINDS[m.kind]().check_system(system, m.settings)

    def record(self) -> dict[str, Any]:
        return {"systems": list(self.systems), "methods": [m.record() for m in self.methods],
                "seeds": list(self.seeds), "cache_dir": self.cache_dir}
