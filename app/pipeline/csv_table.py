"""The CSV tables of a journey bundle (``gps.csv``, ``detections.csv``), read strictly.

Row numbers in messages are line numbers of the file as a user sees it in an editor or spreadsheet:
the header is row 1, the first data row is row 2. Blank rows are skipped; extra columns are ignored;
values are stripped of surrounding whitespace.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from typing import Sequence

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


def read_table(text: str, file_name: str, required: Sequence[str],
               optional: Sequence[str] = ()) -> list[TableRow]:
    """Rows of a CSV with a mandatory header; an absent optional column reads as empty values."""
    expected = ",".join([*required, *optional])
    reader = csv.reader(io.StringIO(text, newline=""))
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
        rows = []
        for fields in reader:
            if not any(f.strip() for f in fields):
                continue
            values = {c: fields[i].strip() for i, c in enumerate(columns) if c and i < len(fields)}
            rows.append(TableRow(reader.line_num, values))
    except csv.Error as exc:
        raise BundleError(f"{file_name} is not valid CSV near row {reader.line_num}: {exc}") from None
    return rows


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
