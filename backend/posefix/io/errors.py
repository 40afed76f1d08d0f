"""Errors raised by the run and edit readers."""

from __future__ import annotations

__all__ = ["RunFormatError", "EditsFormatError", "EditMatchError", "OrientationDerivedWarning"]


class RunFormatError(ValueError):
    """Bad input: names the file, the line (1-based, or None when not line-based) and the field.

    ``str()`` reads ``file:line: field: message`` so it can be printed as one line.
    """

    def __init__(self, file: str, line: int | None, field: str | None, message: str):
        self.file = str(file)
        self.line = line
        self.field = field
        self.message = message
        super().__init__(self._render())

    def _render(self) -> str:
        where = self.file if self.line is None else f"{self.file}:{self.line}"
        line_txt = "" if self.line is not None else " (line n/a)"
        field_txt = self.field if self.field else "(whole file)"
        return f"{where}{line_txt}: field {field_txt}: {self.message}"

    def __reduce__(self):  # keep picklable across processes (worker jobs)
        return (type(self), (self.file, self.line, self.field, self.message))


class EditsFormatError(RunFormatError):
    """A malformed edits file (EDITS.json)."""


class EditMatchError(RunFormatError):
    """An edit whose time names no sample of the run (to the millisecond), or names one twice."""


class OrientationDerivedWarning(UserWarning):
    """The input had no orientation; heading was derived from the track (roll = pitch = 0)."""
