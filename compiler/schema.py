"""The compiler's intermediate representations: frozen dataclasses, one per pass boundary.

``ProblemSpec`` (parse) → ``SymbolicProblem`` (symbolic, checked) → ``CodegenData`` (lower) → text (render).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .errors import Location

# The newest schema this compiler reads; every version in SUPPORTED_SCHEMAS is read (schema 1 and 2 files stay valid
# and compile to the same bytes as before the later schemas existed).
SCHEMA_VERSION = 3
SUPPORTED_SCHEMAS = (1, 2, 3)


@dataclasses.dataclass(frozen=True)
class Expr:
    """Expression text from the spec with where it came from.

    ``number`` is set when YAML itself gave a number (so no expression parsing is needed); ``offset_ok`` says whether
    a column inside ``text`` maps linearly onto the file (single-line plain or quoted scalars).
    """

    text: str
    loc: Location
    number: float | None = None
    offset_ok: bool = False
    quote: int = 0  # columns taken by an opening quote

    def at(self, col_offset: int) -> Location:
        """The file location of a 0-based column inside ``text``."""
        if not self.offset_ok:
            return self.loc
        return dataclasses.replace(self.loc, col=self.loc.col + self.quote + col_offset)


@dataclasses.dataclass(frozen=True)
class Distribution:
    """Schema 3: a parameter's ``uncertain: {KIND: [numbers]}``, numbers as YAML gave them (no expressions)."""

    kind: str  # "uniform" | "normal" | "lognormal" | "choice"
    args: tuple[float, ...]  # (lo, hi) | (mean, std) | (mu, sigma) | (v1, ...)
    loc: Location  # the list of numbers
    arg_locs: tuple[Location, ...]


@dataclasses.dataclass(frozen=True)
class Parameter:
    name: str
    loc: Location
    value: Expr
    description: str = ""
    units: str = ""
    learnable: bool = False
    guess: Expr | None = None
    # Schema 3: the distribution of an uncertain parameter, and its physical domain `bounds: [lo, hi]` (numbers).
    uncertain: Distribution | None = None
    bounds: tuple[float, float] | None = None
    bounds_loc: Location | None = None


@dataclasses.dataclass(frozen=True)
class Scenario:
    """Schema 3: one explicit scenario, ``{name: value, ...}`` in the order written."""

    loc: Location
    values: tuple[tuple[str, float, Location], ...]  # (parameter, value, where its key is)


@dataclasses.dataclass(frozen=True)
class Robust:
    """Schema 3: ``robust: {objective: mean | worst | {cvar: alpha}, samples: N, seed: S}``."""

    loc: Location
    objective: str  # "mean" | "worst" | "cvar"
    alpha: float | None  # cvar's alpha, else None
    alpha_loc: Location | None
    samples: int
    seed: int
    # Where the values of `samples` and `seed` were written; None where they took their defaults.
    samples_loc: Location | None = None
    seed_loc: Location | None = None


@dataclasses.dataclass(frozen=True)
class NoiseLevel:
    """Schema 3: one state's entry under `noise.process` or `noise.observation`."""

    state: str
    level: float
    loc: Location  # the state's key
    value_loc: Location
    part: str  # "process" | "observation"


@dataclasses.dataclass(frozen=True)
class Noise:
    """Schema 3: ``noise: {process: {STATE: sigma}, observation: {STATE: std}}``; None where a part is absent."""

    loc: Location
    process: tuple[NoiseLevel, ...] | None = None
    observation: tuple[NoiseLevel, ...] | None = None


@dataclasses.dataclass(frozen=True)
class Variable:
    """A state or a control."""

    name: str
    loc: Location
    kind: str  # "state" | "control"
    initial: Expr | None = None
    final: Expr | None = None
    lower: Expr | None = None
    upper: Expr | None = None
    bounds_loc: Location | None = None
    description: str = ""
    units: str = ""


@dataclasses.dataclass(frozen=True)
class Named:
    """A named expression: a definition or one state's equation."""

    name: str
    loc: Location
    expr: Expr


@dataclasses.dataclass(frozen=True)
class FreeHorizon:
    """Schema 2: the final time as a decision variable, ``horizon: {free: true, guess: G, bounds: [lo, hi]}``."""

    loc: Location
    guess: Expr
    lower: Expr
    upper: Expr
    bounds_loc: Location


@dataclasses.dataclass(frozen=True)
class PathConstraint:
    """Schema 2: ``lower <= expression(x, u, t, p) <= upper`` along the whole trajectory."""

    name: str
    loc: Location
    expr: Expr
    lower: Expr
    upper: Expr
    bounds_loc: Location
    description: str = ""


@dataclasses.dataclass(frozen=True)
class ProblemSpec:
    """What the parse pass read: structure and types checked, expressions still text."""

    file: str
    lines: tuple[str, ...]
    sha256: str
    schema: int
    name: str
    name_loc: Location
    title: str
    description: str
    source: str
    parameters: tuple[Parameter, ...]
    definitions: tuple[Named, ...]
    states: tuple[Variable, ...]
    controls: tuple[Variable, ...]
    dynamics: tuple[Named, ...]
    dynamics_loc: Location
    sense: str
    running: Expr
    terminal: Expr | None
    horizon: Expr  # the fixed final time, or the guess of a free one
    reference: tuple[tuple[str, Any], ...]
    # Schema 2 only; the defaults are what a schema 1 spec means.
    free_horizon: FreeHorizon | None = None
    path_constraints: tuple[PathConstraint, ...] = ()
    # Schema 3 only (uncertainty); the defaults are what a schema 1 or 2 spec means.
    scenarios: tuple[Scenario, ...] = ()
    scenarios_loc: Location | None = None
    robust: Robust | None = None
    noise: Noise | None = None


@dataclasses.dataclass(frozen=True)
class SymbolicProblem:
    """Sympy expressions for everything, in the spec's own sense (not yet negated), plus evaluated constants."""

    spec: ProblemSpec
    states: tuple[Any, ...]  # sympy Symbols, in order
    controls: tuple[Any, ...]
    params: tuple[Any, ...]
    time: Any
    dynamics: tuple[Any, ...]  # one sympy expression per state
    running: Any
    terminal: Any
    param_values: tuple[float, ...]
    guesses: tuple[float | None, ...]
    x0: tuple[float, ...]
    x_lower: tuple[float, ...]
    x_upper: tuple[float, ...]
    u_lower: tuple[float, ...]
    u_upper: tuple[float, ...]
    x_final: tuple[float | None, ...]
    horizon: float  # the fixed final time, or the guess of a free one
    # Parameters that initial values, bounds, final values or the horizon were evaluated with, in spec order.
    structural_params: tuple[str, ...] = ()
    # Schema 2: (lower, upper) of a free final time, else None; one expression and bound pair per path constraint.
    horizon_bounds: tuple[float, float] | None = None
    path: tuple[Any, ...] = ()
    path_lower: tuple[float, ...] = ()
    path_upper: tuple[float, ...] = ()

    @property
    def free_horizon(self) -> bool:
        return self.horizon_bounds is not None


@dataclasses.dataclass(frozen=True)
class CodegenFunction:
    """One generated function: argument unpacking, CSE temporaries and outputs, all as printed strings."""

    name: str
    doc: str
    args: tuple[str, ...]
    unpack: tuple[tuple[str, str], ...]  # (local name, source expression)
    temps: tuple[tuple[str, str], ...]  # (temporary, printed expression)
    result: str  # printed return expression


@dataclasses.dataclass(frozen=True)
class CodegenData:
    """Everything the template needs, already decided and printed: templates only lay it out."""

    header: str
    module_doc: str
    class_name: str
    imports: tuple[str, ...]
    metadata: tuple[tuple[str, str], ...]  # (attribute, Python literal)
    functions: tuple[CodegenFunction, ...]
    summary: tuple[tuple[str, str], ...]  # human-readable equations for `myriadc show`
