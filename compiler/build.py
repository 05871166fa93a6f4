"""The pipeline and the build driver: ``compile_spec = render ∘ lower ∘ check ∘ symbolic ∘ parse``.

The passes are the modules :mod:`.parse`, :mod:`.symbolic` (expressions through the grammar of :mod:`.expressions`),
:mod:`.checks`, :mod:`.lower` (printing, via :mod:`.printer`, the Hamiltonian, costates and u* that
:mod:`.optimal_control` derives) and :mod:`.render`.

``build`` compiles every spec first and writes only if all of them compiled, so a bad spec never leaves a partial
output behind; files are replaced atomically and only when their bytes change.
"""

from __future__ import annotations

import dataclasses
import difflib
import os
import tempfile
from pathlib import Path

from . import checks, parse, render, symbolic
from . import lower as lower_mod
from .errors import CodegenError, ErrorLog, Location, SpecError, flatten
from .schema import CodegenData, SymbolicProblem

__all__ = ["DEFAULT_OUT", "BuildResult", "Compiled", "build", "compile_file", "compile_spec", "spec_files"]

# runtime/systems beside this package (the repository layout, and site-packages/myriad/ in a wheel).
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "runtime" / "systems"


@dataclasses.dataclass(frozen=True)
class Compiled:
    name: str
    text: str
    data: CodegenData
    symbolic: SymbolicProblem


def _symbolic(text: str, display: str) -> SymbolicProblem:
    """Parse, symbolic and check: every independent error of the spec, raised together (:class:`SpecErrors`).

    A pass stops the pipeline only where what follows depends on it: a parse error stops everything (there is no
    spec to read), a bad name stops the symbolic pass (expressions resolve by name); the symbolic pass hands the
    check pass a partial problem (None where a field failed), so an undeclared symbol and a negative horizon are
    both reported.
    """
    spec = parse.parse_spec(text, display)
    log = ErrorLog()
    checks.check_names(spec, log)
    log.stop()
    checks.check_equations(spec, log)
    sym = symbolic.to_symbolic(spec, log)
    checks.check_problem(sym, log)
    log.stop()
    return sym


def compile_spec(text: str, display: str = "<spec>") -> Compiled:
    """Compile spec text to module text. Raises SpecError (bad spec) or CodegenError."""
    sym = _symbolic(text, display)
    try:
        data = lower_mod.lower(sym, display)
    except CodegenError as exc:
        # A valid-looking spec whose derived code cannot be emitted (e.g. log(0) in one branch): report it at the
        # spec field it came from, like any other spec error.
        raise _at_field(sym, exc) from None
    return Compiled(sym.spec.name, render.render_system(data), data, sym)


def _at_field(sym: SymbolicProblem, exc: CodegenError) -> SpecError:
    spec = sym.spec
    field = getattr(exc, "field", "") or ""
    path = {f"path_constraints.{c.name}": c.expr.loc for c in spec.path_constraints}
    if field in path:
        loc = path[field]
    elif field.startswith("cost.terminal") and spec.terminal is not None:
        loc = spec.terminal.loc
    elif field.startswith("cost"):
        loc = spec.running.loc
    else:
        loc = spec.dynamics_loc
    line = spec.lines[loc.line - 1] if 0 < loc.line <= len(spec.lines) else None
    return SpecError(f"cannot generate code: {exc}", loc, line)


def _display(path: Path) -> str:
    """The path shown in messages and headers: relative to the working directory when inside it."""
    try:
        rel = os.path.relpath(path)
    except ValueError:
        return str(path)
    return str(path) if rel.startswith("..") else rel


def _read(path: Path, display: str) -> str:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SpecError(f"cannot read file: {exc.strerror}", Location(display, 1, 1)) from None
    if len(raw) > parse.MAX_SPEC_BYTES:
        raise SpecError(f"spec is larger than {parse.MAX_SPEC_BYTES} bytes", Location(display, 1, 1))
    return parse.decode_spec(raw, display)


def compile_file(path: str | os.PathLike, display: str | None = None) -> Compiled:
    path = Path(path)
    display = display or _display(path)
    return compile_spec(_read(path, display), display)


def check_file(path: str | os.PathLike) -> SymbolicProblem:
    """Validate only (parse, symbolic, checks): no code is generated."""
    path = Path(path)
    display = _display(path)
    return _symbolic(_read(path, display), display)


def spec_files(paths) -> list[Path]:
    """Expand directories to their *.yaml files (sorted); keep files as given; reject what does not exist."""
    out = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out.extend(sorted(p.glob("*.yaml")))
        elif p.exists():
            out.append(p)
        else:
            raise FileNotFoundError(str(p))
    return out


@dataclasses.dataclass
class BuildResult:
    written: list[str] = dataclasses.field(default_factory=list)
    unchanged: list[str] = dataclasses.field(default_factory=list)
    stale: list[str] = dataclasses.field(default_factory=list)
    diffs: list[str] = dataclasses.field(default_factory=list)
    errors: list[Exception] = dataclasses.field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors and not self.stale


def _is_generated(path: Path) -> bool:
    try:
        with path.open("r", encoding="utf-8") as fh:
            return fh.readline().startswith(render.REGISTRY_HEADER)
    except (OSError, UnicodeDecodeError):
        return False


def _umask() -> int:
    mask = os.umask(0)  # the only portable way to read it is to set it
    os.umask(mask)
    return mask


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".myriadc-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600: the file follows the umask like any other
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_outputs(outputs: dict[Path, str], out: Path, check: bool, result: BuildResult) -> None:
    """Write each changed file atomically into ``out`` (created if missing), or with ``check`` only record which
    ones differ (with a unified diff); both `myriadc build` and `myriadc card` end here."""
    if not check:
        out.mkdir(parents=True, exist_ok=True)
    for path, text in outputs.items():
        old = path.read_text(encoding="utf-8") if path.exists() else None
        shown = _display(path)
        if old == text:
            result.unchanged.append(shown)
        elif check:
            result.stale.append(shown)
            result.diffs.append("".join(difflib.unified_diff(
                (old or "").splitlines(keepends=True), text.splitlines(keepends=True),
                fromfile=f"{shown} (committed)", tofile=f"{shown} (from specs)")))
        else:
            _write_atomic(path, text)
            result.written.append(shown)


def build(paths, out_dir: str | os.PathLike | None = None, check: bool = False) -> BuildResult:
    """Compile specs into ``out_dir`` (default: the package's runtime/systems) with a registry ``__init__.py``.

    With ``check=True`` nothing is written: outputs whose bytes differ are reported as stale with a unified diff.
    """
    out = Path(out_dir) if out_dir is not None else DEFAULT_OUT
    result = BuildResult()
    compiled: list[Compiled] = []
    names: dict[str, str] = {}
    for path in spec_files(paths):
        try:
            c = compile_file(path)
        except SpecError as exc:  # one, or several (SpecErrors)
            result.errors.extend(flatten(exc))
            continue
        except CodegenError as exc:
            result.errors.append(exc)
            continue
        if c.name in names:
            result.errors.append(SpecError(f"system `{c.name}` is also defined by {names[c.name]}",
                                           Location(_display(path), 1, 1, ("name",))))
            continue
        names[c.name] = _display(path)
        compiled.append(c)
    if result.errors:
        return result  # all or nothing: a bad spec leaves no output behind

    outputs = {out / f"{c.name}.py": c.text for c in compiled}
    existing = (
        {p.stem for p in out.glob("*.py") if p.name != "__init__.py" and _is_generated(p)} if out.is_dir() else set()
    )
    outputs[out / "__init__.py"] = render.render_registry(sorted(existing | set(names)))

    write_outputs(outputs, out, check, result)
    return result
