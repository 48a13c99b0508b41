"""Comma-separated tables read by column name, with errors that name the file and the line.

A phone log's tables (``dtmbnav/field/phone_logs.py``: a GnssLogger row type's rows, a Sensor Logger
CSV file) are read through a :class:`Table`: each row's text and its line in the file, its header's
names, and the fields split only where asked. Rows are split as the csv module reads them (a quoted
field may hold a comma); every row must have as many fields as its header names
(:func:`check_lengths`).

Numbers: :func:`float_column` and :func:`integer_column` read a column as Python's ``float`` and ``int``
read each cell, refusing an empty cell, NaN and inf with the cell's line. A long table (an hour of a
sensor at 100 Hz is 360 000 rows) would take seconds so; :func:`parse_numbers` first reads its columns
in one pass of numpy's C parser (:func:`numpy.loadtxt`), and the column readers take those columns
where numpy read them all (finite): numpy reads a number as Python does, and what it refuses (quotes,
``1_000``, an empty or malformed cell) is left to the cell-by-cell reading, so the values and the
errors are the same either way.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from itertools import repeat
from pathlib import Path

import numpy as np


@dataclass
class Table:
    """Rows of one row type (GnssLogger) or one CSV file, with their header's names.

    ``texts`` holds each row's text (a GnssLogger row's without its type), ``lines`` its line in the
    file (1-based); ``parsed`` the columns :func:`parse_numbers` read, by (column, ``"i"`` or ``"f"``).
    """

    where: str
    header: tuple[str, ...]
    header_line: int
    texts: list[str] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    parsed: dict[tuple[int, str], np.ndarray] = field(default_factory=dict)

    def index(self, names: Sequence[str]) -> int | None:
        """Column of the first of ``names`` the header has (case-insensitive), None if none."""
        lowered = [h.lower() for h in self.header]
        for name in names:
            if name.lower() in lowered:
                return lowered.index(name.lower())
        return None

    def need(self, names: Sequence[str]) -> int:
        """Column of the first of ``names`` the header has; ValueError naming the header otherwise."""
        column = self.index(names)
        if column is None:
            also = f" (or {', '.join(names[1:])})" if len(names) > 1 else ""
            raise ValueError(f"{self.where}: the header (line {self.header_line}) has no column {names[0]}{also}")
        return column

    @cached_property
    def quoted(self) -> bool:
        """Whether a row holds a quote character."""
        return '"' in "".join(self.texts)  # one scan in C, faster than a test per row

    @cached_property
    def fields(self) -> list[list[str]]:
        """Each row's fields as the csv module reads them (an empty row: one empty field); a
        :class:`RowError` for the first row it cannot split."""
        if not self.quoted:  # without quotes the csv module splits at every comma, as str.split does faster
            return [text.split(",") for text in self.texts]
        return [csv_fields(text, self.where, line) for text, line in zip(self.texts, self.lines)]

    def cells(self, column: int) -> list[str]:
        """The fields of one column, surrounding blanks stripped."""
        return [row[column].strip() for row in self.fields]

    def subset(self, keep: Sequence[int]) -> Table:
        """The rows ``keep`` (indices) as a table of their own."""
        return Table(self.where, self.header, self.header_line, [self.texts[i] for i in keep],
                     [self.lines[i] for i in keep])


class RowError(ValueError):
    """A row the csv module cannot split (a quote not closed, text after a closing quote, a NUL character).

    Attributes
    ----------
    line : int
        The row's line in its file (1-based).
    """

    def __init__(self, where: str, line: int, reason: str) -> None:
        super().__init__(f"{where}:{line}: malformed quoting ({reason})")
        self.line = line


def csv_fields(text: str, where: str, line: int) -> list[str]:
    """One row's fields as the csv module reads them (strictly: a malformed quote is a :class:`RowError`)."""
    try:
        return next(csv.reader((text,), strict=True), [""])
    except csv.Error as exc:
        raise RowError(where, line, str(exc)) from None


def read_text(path: str | Path, data: bytes | None = None) -> str:
    """A log's text (UTF-8, a byte-order mark dropped); ValueError for a missing, empty or binary file."""
    if data is None:
        path = Path(path)
        if not path.exists():
            raise ValueError(f"{path}: no such file")
        if not path.is_file():
            raise ValueError(f"{path}: not a file")
        data = path.read_bytes()
    if not data.strip():
        raise ValueError(f"{path}: empty file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text log (byte {exc.start} is not UTF-8)") from None


def _length_error(table: Table, label: str, leading: int, last_line: int,
                  complete: bool) -> tuple[int, str] | None:
    """The first row whose field count differs from its header's: its line and the message; None if none.

    A short row on the file's last line, where the file ends without a line break, is a truncated file.
    ``leading`` fields (a GnssLogger row's type) come before those the table keeps and are counted too.
    """
    if table.quoted:
        try:
            counts = np.fromiter(map(len, table.fields), np.int64, len(table.texts))
        except RowError as exc:  # a row the csv module cannot split is the error of its line
            return exc.line, str(exc)
    else:  # as many fields as commas and one, without splitting the rows
        counts = np.fromiter(map(str.count, table.texts, repeat(",")), np.int64, len(table.texts)) + 1
    bad = np.flatnonzero(counts != len(table.header))
    if not bad.size:
        return None
    number = table.lines[bad[0]]
    have, want = int(counts[bad[0]]) + leading, len(table.header) + leading
    if number == last_line and not complete and have < want:
        return number, (f"{table.where}:{number}: truncated {label}row: {have} of the header's {want} fields (the "
                        "file ends inside it)")
    return number, (f"{table.where}:{number}: {label}row has {have} fields, its header (line {table.header_line}) "
                    f"names {want}")


def check_lengths(tables: Iterable[tuple[Table, str]], last_line: int, complete: bool, leading: int = 0) -> None:
    """Check that every row has as many fields as its header names.

    Parameters
    ----------
    tables : iterable of (Table, str)
        The tables of one file, each with its rows' label for the messages (e.g. ``"Gyro "``).
    last_line : int
        The file's last line (1-based), and ``complete``: whether a line break ends it.
    leading : int
        Fields before those the tables keep (a GnssLogger row's type), counted in the messages.

    Raises
    ------
    ValueError
        For the row, first in the file, whose field count differs from its header's (a short one on the
        last line of a file that ends without a line break: a truncated file), naming the file and line.
    """
    errors = [error for table, label in tables if (error := _length_error(table, label, leading, last_line,
                                                                          complete))]
    if errors:
        raise ValueError(min(errors)[1])


def parse_numbers(table: Table, integers: Sequence[str], reals: Sequence[str]) -> None:
    """Read the columns ``integers`` (int64) and ``reals`` (float64) of a long table, by name, in one pass of
    numpy's C parser into ``table.parsed``, where :func:`integer_column` and :func:`float_column` take them.

    What numpy refuses or reads as NaN or inf is left to those, which read cell by cell as Python's ``int``
    and ``float`` do, and name the line of a bad cell: numpy only speeds up what they read the same. A table
    with quotes is left to them too (loadtxt's quoting is not the csv module's, and its rows are few).
    """
    if table.quoted or not table.texts:
        return
    kinds = {column: kind for names, kind in ((integers, "i"), (reals, "f")) for name in names
             if (column := table.index((name,))) is not None}

    def load(columns: list[int]) -> bool:
        """Parse ``columns`` into ``table.parsed`` (those numpy read whole and finite); False if it refused a cell."""
        dtype = [(str(c), np.int64 if kinds[c] == "i" else np.float64) for c in columns]
        try:
            data = np.loadtxt(table.texts, delimiter=",", comments=None, usecols=columns, dtype=dtype, ndmin=1)
        except ValueError:
            return False
        for c in columns:
            values = np.ascontiguousarray(data[str(c)])
            if len(values) == len(table.texts) and (kinds[c] == "i" or np.isfinite(values).all()):
                values.flags.writeable = False  # shared by every reader of the column
                table.parsed[c, kinds[c]] = values
        return True

    if not load(list(kinds)):  # one refused cell: the other columns still go at numpy's speed
        for column in kinds:
            load([column])


def float_column(table: Table, column: int, name: str, empty_ok: bool = False) -> np.ndarray:
    """A column as float64; an empty field is NaN where ``empty_ok``, else (like NaN or inf) a ValueError."""
    if (column, "f") in table.parsed:
        return table.parsed[column, "f"]
    out = []
    for text, number in zip(table.cells(column), table.lines):
        if text == "" and empty_ok:
            out.append(math.nan)
            continue
        try:
            value = float(text)
        except ValueError:
            what = "empty" if text == "" else f"not a number: {text!r}"
            raise ValueError(f"{table.where}:{number}: {name} is {what}") from None
        if not math.isfinite(value):
            raise ValueError(f"{table.where}:{number}: {name} is {text} (NaN and inf are refused)")
        out.append(value)
    return np.array(out, dtype=np.float64)


def integer_column(table: Table, column: int, name: str) -> np.ndarray:
    """A column of whole numbers (timestamps) as int64, read exactly; ValueError naming the line otherwise."""
    if (column, "i") in table.parsed:
        return table.parsed[column, "i"]
    out = []
    for text, number in zip(table.cells(column), table.lines):
        try:
            out.append(int(text))
        except ValueError:
            what = "empty" if text == "" else f"not a whole number: {text!r}"
            raise ValueError(f"{table.where}:{number}: {name} is {what}") from None
    return np.array(out, dtype=np.int64)


def csv_table(where: str, text: str) -> Table:
    """A CSV file's rows split by its header (first line); ValueError for a row of another length."""
    lines = text.splitlines()
    table = Table(where, tuple(name.strip() for name in csv_fields(lines[0], where, 1)), 1)
    table.lines = [number for number, line in enumerate(lines[1:], 2) if line and not line.isspace()]
    table.texts = [lines[number - 1] for number in table.lines]
    check_lengths([(table, "")], len(lines), text.endswith(("\n", "\r")))
    return table
