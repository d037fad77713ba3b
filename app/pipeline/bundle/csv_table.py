"""The CSV tables of a journey bundle (``gps.csv``, ``detections.csv``), read strictly.

Row numbers in messages are line numbers of the file as a user sees it in an editor or spreadsheet:
the header is row 1, the first data row is row 2. Blank rows are skipped; extra columns are ignored;
values are stripped of surrounding whitespace. Tables stream: a row is parsed, checked and
dropped before the next is read, and a row limit stops a long table as soon as it is passed.

Every value a bundle carries into the job is bounded here or by its reader, so that input fails
the upload with a message naming file, row and field rather than the job with an internal error:
numbers are finite and in the range the field can physically take (``parse_float``), text is at
most ``MAX_TEXT_CHARS`` long and holds no control character (``check_text``: PostgreSQL text
cannot hold NUL, and a newline in a logged id forges log lines). Values echoed in messages are
shortened and escaped (``shown``).
"""

from __future__ import annotations

import csv
import io
import math
import operator
import re
from typing import BinaryIO, Iterator, Sequence, TextIO

from app.pipeline.types import BundleError

# The width of the service's text columns (camera ids, classes, track ids): longer text is refused
# at the upload rather than failing the job when it is stored.
MAX_TEXT_CHARS = 200
# C0 and C1 controls, DEL, and the Unicode line and paragraph separators (a line break to some
# log readers).
CONTROL_CHARS = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")
_SHOWN_CHARS = 60


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


def quoted(text: str) -> str:
    """``text`` quoted as a message may echo it: control characters escaped, cut to
    ``_SHOWN_CHARS`` characters (a 10,000-character value is not sent back whole)."""
    if len(text) <= _SHOWN_CHARS:
        return repr(text)
    return f"{text[:_SHOWN_CHARS]!r}... ({len(text)} characters)"


def shown(text: str) -> str:
    """``text`` as is when short and printable, else ``quoted``."""
    if 0 < len(text) <= _SHOWN_CHARS and text.isprintable() and text.strip() == text:
        return text
    return quoted(text)


def check_text(text: str, where: str, max_chars: int = MAX_TEXT_CHARS) -> str:
    """``text`` unchanged, or a BundleError naming ``where`` when it is longer than ``max_chars``
    or holds a control character."""
    if len(text) > max_chars:
        raise BundleError(f"{where} is {len(text)} characters long, more than the limit of "
                          f"{max_chars}")
    bad = CONTROL_CHARS.search(text)
    if bad:
        raise BundleError(f"{where} holds a control character ({bad.group()!r} at character "
                          f"{bad.start() + 1}); ids and classes must be printable text")
    return text


def parse_float(text: str, where: str, low: float = -math.inf, high: float = math.inf,
                unit: str = "") -> float:
    """A finite decimal number within [low, high], or a BundleError naming ``where`` (e.g.
    "gps.csv row 7: lat")."""
    try:
        value = float(text)
    except ValueError:
        raise BundleError(f"{where} is {quoted(text) if text else 'empty'}, expected a number"
                          ) from None
    if not math.isfinite(value):
        raise BundleError(f"{where} is {quoted(text)}, expected a finite number")
    if not low <= value <= high:
        raise BundleError(f"{where} is {text if len(text) <= _SHOWN_CHARS else f'{value:g}'}, "
                          f"outside [{low:g}, {high:g}]{unit}")
    return value
