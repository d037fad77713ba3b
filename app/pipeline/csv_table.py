"""The CSV tables of a journey bundle (``gps.csv``, ``detections.csv``), read strictly.

Row numbers in messages are line numbers of the file as a user sees it in an editor or spreadsheet:
the header is row 1, the first data row is row 2. Blank rows are skipped; extra columns are ignored;
values are stripped of surrounding whitespace. Tables stream: a row is parsed, checked and
dropped before the next is read, and a row limit stops a long table as soon as it is passed.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from typing import BinaryIO, Iterator, Sequence, TextIO

from app.pipeline.types import BundleError


@dataclass(frozen=True)
class TableRow:
    row: int
    values: dict[str, str]

    def __getitem__(self, column: str) -> str:
        return self.values.get(column, "")


def decode_text(data: bytes, file_name: str) -> str:
    """UTF-8 (with or without a byte-order mark, as spreadsheets write it) -> str."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BundleError(f"{file_name} is not UTF-8 text (byte {exc.start})") from None


def text_lines(source: str | BinaryIO) -> TextIO:
    """A table's text as a stream of lines: a str, or a binary stream decoded as it is read (UTF-8
    with or without a byte-order mark), so a table is never held whole in memory."""
    if isinstance(source, str):
        return io.StringIO(source, newline="")
    return io.TextIOWrapper(source, encoding="utf-8-sig", newline="")


def iter_table(source: str | BinaryIO, file_name: str, required: Sequence[str],
               optional: Sequence[str] = (), *, max_rows: int | None = None) -> Iterator[TableRow]:
    """Rows of a CSV with a mandatory header, one at a time; an absent optional column reads as
    empty values. More than ``max_rows`` data rows is a BundleError raised as the row after the
    limit is read, before anything beyond it is parsed."""
    expected = ",".join([*required, *optional])
    reader = csv.reader(text_lines(source))
    n_rows = 0
    try:
        header = next(reader, None)
        if header is None:
            raise BundleError(f"{file_name} is empty; it needs the header row {expected}")
        columns = [c.strip() for c in header]
        if not set(columns) & set(required):
            raise BundleError(f"{file_name} has no header row (or is not comma-separated); its "
                              f"first row must be {expected} "
                              f"(got {','.join(columns)[:200]})")
        missing = [c for c in required if c not in columns]
        if missing:
            raise BundleError(f"{file_name} header lacks column(s) {', '.join(missing)}; expected "
                              f"{expected} (got {','.join(columns)[:200]})")
        wanted = [(i, c) for i, c in enumerate(columns) if c in (*required, *optional)]
        for fields in reader:
            if not any(f.strip() for f in fields):
                continue
            n_rows += 1
            if max_rows is not None and n_rows > max_rows:
                raise BundleError(f"{file_name} has more than {max_rows} rows, the limit per "
                                  "journey; split the journey into shorter ones")
            yield TableRow(reader.line_num,
                           {c: fields[i].strip() for i, c in wanted if i < len(fields)})
    except csv.Error as exc:
        raise BundleError(f"{file_name} is not valid CSV near row {reader.line_num}: {exc}") from None
    except UnicodeDecodeError:
        raise BundleError(f"{file_name} is not UTF-8 text (near row {reader.line_num + 1})") from None


def parse_float(text: str, where: str) -> float:
    """A finite decimal number, or a BundleError naming ``where`` (e.g. "gps.csv row 7: lat")."""
    try:
        value = float(text)
    except ValueError:
        shown = repr(text[:40]) if text else "empty"
        raise BundleError(f"{where} is {shown}, expected a number") from None
    if not math.isfinite(value):
        raise BundleError(f"{where} is {text!r}, expected a finite number")
    return value
