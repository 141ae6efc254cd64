"""The one exception for bad input (it says what is wrong and where: file, line, column or field), and the
stop a caller asked for."""

from __future__ import annotations


class InputError(ValueError):
    """Bad input from a user: a file, a field, a value. Never a bug in this library."""

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        line: int | None = None,
        column: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column

    def __str__(self) -> str:
        where = []
        if self.file:
            where.append(str(self.file))
        if self.line is not None:
            where.append(f"line {self.line}")
        if self.column:
            where.append(f"column '{self.column}'")
        return f"{', '.join(where)}: {self.message}" if where else self.message


class Cancelled(Exception):
    """A long computation (a solve, a plan, a draw of configurations) stopped because its caller asked it to."""
