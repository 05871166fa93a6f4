"""Errors that point at the spec, like a compiler's.

Every user-facing failure is a :class:`SpecError` carrying the file, 1-based line and column, and the field path, and
prints as ``specs/x.yaml:12:5: error: <what>, <what was expected>; <how to fix>`` followed by the offending line.
"""

from __future__ import annotations

import dataclasses

__all__ = ["SpecError", "SpecErrors", "CodegenError", "Location"]


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


class SpecErrors(Exception):
    """Several spec errors found in one pass (reported together so a user fixes them in one go)."""

    def __init__(self, errors: list[SpecError]):
        super().__init__("\n".join(e.one_line() for e in errors))
        self.errors = errors

    def __str__(self) -> str:
        return "\n".join(str(e) for e in self.errors)


class CodegenError(Exception):
    """The spec is valid but uses something the code printer cannot emit; names the function and the field."""
