"""Logging of the service, its workers and the command line: one record, one line.

Log messages interpolate what clients send (camera ids, classes, frame names, the reasons a bundle
was refused, request paths), and a newline in any of them forged a whole log line (issue 70). Rather
than escape call by call, ``EscapeControlCharacters`` escapes the control characters of every
formatted message on the handlers ``configure`` sets up (``signmap serve``, the embedded worker's
job processes, ``signmap process``) and on Celery's (``worker.celery_app``). Tracebacks keep their
line breaks: they are appended by the formatter after the message.
"""

from __future__ import annotations

import logging
import re

FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
# C0 and C1 controls, DEL, and the Unicode line and paragraph separators.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def escape_controls(text: str) -> str:
    """``text`` with each control character written as its Python escape (``\\n``, ``\\x1b``)."""
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


class EscapeControlCharacters(logging.Filter):
    """A handler filter: the record's message, formatted, with its control characters escaped."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # noqa: BLE001 - a broken record is the handler's to report, not ours
            return True
        escaped = escape_controls(message)
        if escaped != message:
            record.msg, record.args = escaped, None
        return True


def install(logger: logging.Logger | None = None) -> None:
    """Escape control characters on every handler of ``logger`` (default: the root logger)."""
    for handler in (logger or logging.getLogger()).handlers:
        if not any(isinstance(f, EscapeControlCharacters) for f in handler.filters):
            handler.addFilter(EscapeControlCharacters())


def configure(level: int | str) -> None:
    """The root logger at ``level``, one escaped line per record on stderr."""
    logging.basicConfig(level=level, format=FORMAT)
    install()
