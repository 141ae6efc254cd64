"""Reading CSV files the way every data format here does: a header, data rows, and every problem
named by file, line and column."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable

from ..errors import InputError

# No joint angle, length or pixel in a calibration dataset comes near this; beyond it, arithmetic
# on squares overflows, so such a value is reported as bad input rather than computed with.
MAX_MAGNITUDE = 1e9


def table(text: str, name: str) -> tuple[int, list[str], list[tuple[int, list[str]]]]:
    """The header's line number, its column names, and the data rows (line number, fields); blank
    lines left out."""
    try:
        rows = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise InputError(f"not a valid CSV file ({exc})", file=name) from None
    lines = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    if not lines:
        raise InputError("file is empty (a header line and data rows are required)", file=name)
    header_line, header = lines[0]
    if not lines[1:]:
        raise InputError("has a header but no data rows", file=name, line=header_line)
    return header_line, [h.strip() for h in header], lines[1:]


def require_columns(robot: str, columns: Iterable[str], col: dict[str, int], name: str, header_line: int) -> None:
    """InputError for the first column the header lacks, naming the robot whose data format was asked for
    (a file of another robot is the usual cause)."""
    for c in columns:
        if c not in col:
            raise InputError(
                f"missing column '{c}' in the header (the data format of robot {robot}: is the file of another robot?)",
                file=name,
                line=header_line,
                column=c,
            )


class Row:
    """One data row: its fields by column, read with the file, line and column of every problem."""

    def __init__(self, name: str, line: int, fields: list[str], col: dict[str, int]) -> None:
        width = max(col.values(), default=-1) + 1  # the header's length (a repeated name keeps its last place)
        if len(fields) != width:
            raise InputError(f"has {len(fields)} fields but the header has {width}", file=name, line=line)
        self.name, self.line, self.fields, self.col = name, line, fields, col

    def fail(self, message: str, column: str | None = None) -> InputError:
        return InputError(message, file=self.name, line=self.line, column=column)

    def text(self, c: str) -> str:
        return self.fields[self.col[c]].strip()

    def number(self, c: str, *, optional: bool = False) -> float:
        """The column's number; NaN for an empty cell when `optional`."""
        s = self.text(c)
        if not s and optional:
            return math.nan
        try:
            v = float(s)
        except ValueError:
            raise self.fail("is empty" if not s else f"'{s}' is not a number", c) from None
        if not math.isfinite(v):
            raise self.fail(f"'{s}' is not a finite number", c)
        if abs(v) > MAX_MAGNITUDE:
            raise self.fail(f"'{s}' is implausibly large (beyond {MAX_MAGNITUDE:g})", c)
        return v

    def choice(self, c: str, values: dict[str, int]) -> int:
        v = self.text(c)
        if v not in values:
            raise self.fail(f"'{v}' is not one of {', '.join(values)}", c)
        return values[v]
