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
import operator
from typing import BinaryIO, Iterator, Sequence, TextIO

from app.pipeline.types import BundleError


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
               optional: Sequence[str] = (), *, max_rows: int | None = None
               ) -> Iterator[tuple[int, tuple[str, ...]]]:
    """(line number, values) of each row of a CSV with a mandatory header, one at a time: values
    in the order of ``required`` then ``optional``, stripped, "" where the row is short or an
    optional column is absent. More than ``max_rows`` data rows is a BundleError, raised as the
    first row past the limit is read."""
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
        wanted = [*required, *optional]
        # The last column of that name, as a dict of the header would keep; -1: absent.
        position = [max((i for i, c in enumerate(columns) if c == w), default=-1) for w in wanted]
        present = [i for i in position if i >= 0]
        getter = operator.itemgetter(*position) if len(present) == len(position) > 1 else None
        needed = max(present) + 1
        limit = max_rows if max_rows is not None else -1
        for fields in reader:
            if getter is not None and len(fields) >= needed:
                values = tuple(map(str.strip, getter(fields)))
            else:
                values = tuple(fields[i].strip() if 0 <= i < len(fields) else ""
                               for i in position)
            if not any(values) and not any(f.strip() for f in fields):
                continue
            n_rows += 1
            if n_rows == limit + 1:
                raise BundleError(f"{file_name} has more than {max_rows} rows, the limit per "
                                  "journey; split the journey into shorter ones")
            yield reader.line_num, values
    except csv.Error as exc:
        raise BundleError(f"{file_name} is not valid CSV near row {reader.line_num}: {exc}") from None
    except UnicodeDecodeError:
        raise BundleError(f"{file_name} is not UTF-8 text (near row {reader.line_num + 1})"
                          ) from None


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
