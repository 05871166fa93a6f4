"""Errors that point at the spec, like a compiler's.

Every user-facing failure is a :class:`SpecError` carrying the file, 1-based line and column, and the field path, and
prints as ``specs/x.yaml:12:5: error: <what>, <what was expected>; <how to fix>`` followed by the offending line.
The passes collect the independent errors of one spec in an :class:`ErrorLog` and raise them together as
:class:`SpecErrors`, so one run reports all of them (the first :data:`MAX_REPORTED` are printed).
"""

from __future__ import annotations

import dataclasses

__all__ = ["MAX_REPORTED", "CodegenError", "ErrorLog", "Location", "SpecError", "SpecErrors", "Unresolved", "flatten",
           "report"]

# How many errors one run prints; the rest are counted ("... and N more"), so a hostile spec cannot flood a terminal.
MAX_REPORTED = 20


@dataclasses.dataclass(frozen=True)
class Location:
    """A position in a spec file (1-based line and column) and the field path that lives there."""

    file: str
    line: int
    col: int
    path: tuple[str, ...] = ()

    def field(self) -> str:
        return ".".join(self.path) if self.path else "<document>"


class SpecError(Exception):
    """A problem with a spec, reported at a source position."""

    def __init__(self, message: str, loc: Location, source_line: str | None = None):
        super().__init__(message)
        self.message = message
        self.loc = loc
        self.source_line = source_line

    def one_line(self) -> str:
        return f"{self.loc.file}:{self.loc.line}:{self.loc.col}: error: {self.loc.field()}: {self.message}"

    def __str__(self) -> str:
        text = self.one_line()
        if self.source_line is not None:
            caret = " " * max(self.loc.col - 1, 0) + "^"
            text += f"\n    {self.source_line.rstrip()}\n    {caret}"
        return text


class SpecErrors(SpecError):
    """Several independent errors of one spec, reported together so a user fixes them in one go.

    A :class:`SpecError` itself (its message and location are the first error's), so a caller that catches
    ``SpecError`` catches these too; ``errors`` holds them all, in the order the passes found them.
    """

    def __init__(self, errors: list[SpecError]):
        first = errors[0]
        super().__init__(first.message, first.loc, first.source_line)
        self.errors = list(errors)

    def __str__(self) -> str:
        return report(self.errors)


def report(errors: list[SpecError], cap: int = MAX_REPORTED) -> str:
    """The errors as the compiler prints them: at most ``cap``, then how many more were left out."""
    text = "\n".join(str(e) for e in errors[:cap])
    if len(errors) > cap:
        text += f"\n... and {len(errors) - cap} more errors left out (the first {cap} are shown); fix these and rerun"
    return text


def flatten(exc: SpecError) -> list[SpecError]:
    """The single errors inside ``exc`` (one, or each of a SpecErrors)."""
    return list(exc.errors) if isinstance(exc, SpecErrors) else [exc]


class Unresolved(Exception):
    """A field uses a name whose own definition already failed: its error is reported there, not again here."""


class ErrorLog:
    """The errors of one spec, collected across independent fields so one run reports all of them.

    A pass runs each independent unit (a section, a variable, an expression, a check) through :meth:`attempt`; its
    error is recorded and the pass goes on. Where later work depends on a pass's result, the pipeline calls
    :meth:`stop`, which raises what was collected (nothing when the log is empty).
    """

    def __init__(self):
        self.errors: list[SpecError] = []

    def add(self, exc: SpecError) -> None:
        self.errors.extend(flatten(exc))

    def attempt(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)``, or None with its error recorded (nothing is recorded for a field that only
        failed because a field it uses already did)."""
        try:
            return fn(*args, **kwargs)
        except SpecError as exc:
            self.add(exc)
        except Unresolved:
            pass
        return None

    def stop(self) -> None:
        """Raise the errors collected so far: the one error itself, or a :class:`SpecErrors`."""
        if len(self.errors) == 1:
            raise self.errors[0]
        if self.errors:
            raise SpecErrors(self.errors)


class CodegenError(Exception):
    """The spec is valid but uses something the code printer cannot emit; names the function and the field."""
