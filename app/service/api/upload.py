"""Streaming receipt of the ``bundle`` field of a multipart upload: written straight to disk and hashed
as it arrives, the size limit enforced on the running byte count (never buffered in memory)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable

from fastapi import HTTPException, Request, status
from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header

FIELD = "bundle"


@dataclass(frozen=True)
class ReceivedFile:
    sha256: str
    n_bytes: int


class _BundlePart:
    """Multipart callbacks that copy the ``bundle`` part into ``out`` and ignore any other part."""

    def __init__(self, out: BinaryIO):
        self.out = out
        self.digest = hashlib.sha256()
        self.n_bytes = 0
        self.seen = False
        self.finished = False
        self._header_name = b""
        self._header_value = b""
        self._headers: dict[bytes, bytes] = {}
        self._in_bundle = False

    def callbacks(self) -> dict:
        return {
            "on_part_begin": self._part_begin, "on_header_field": self._header_field,
            "on_header_value": self._header_value_cb, "on_header_end": self._header_end,
            "on_headers_finished": self._headers_finished, "on_part_data": self._part_data,
            "on_end": self._end,
        }

    def _part_begin(self) -> None:
        self._headers = {}
        self._in_bundle = False

    def _header_field(self, data: bytes, start: int, end: int) -> None:
        self._header_name += data[start:end]

    def _header_value_cb(self, data: bytes, start: int, end: int) -> None:
        self._header_value += data[start:end]

    def _header_end(self) -> None:
        self._headers[self._header_name.lower()] = self._header_value
        self._header_name, self._header_value = b"", b""

    def _headers_finished(self) -> None:
        _, options = parse_options_header(self._headers.get(b"content-disposition", b""))
        if options.get(b"name") == FIELD.encode():
            if self.seen:
                raise HTTPException(422,
                                    f"give the multipart field '{FIELD}' once")
            self.seen = self._in_bundle = True

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        if self._in_bundle:
            chunk = data[start:end]
            self.out.write(chunk)
            self.digest.update(chunk)
            self.n_bytes += len(chunk)

    def _end(self) -> None:
        self.finished = True


async def receive_bundle(request: Request, dest: Path, max_bytes: int,
                         on_bytes: Callable[[int], None] | None = None) -> ReceivedFile:
    """Write the upload's ``bundle`` field to ``dest``. Raises HTTPException 413 as soon as the body
    passes ``max_bytes``, 415/400/422 for a body that is not a multipart form with that field; ``dest``
    is removed on every error. ``on_bytes`` is told the size of each chunk of the body as it is
    read (the per-key byte limit counts what was sent, valid or not)."""
    content_type, options = parse_options_header(request.headers.get("content-type"))
    if content_type != b"multipart/form-data" or not options.get(b"boundary"):
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            f"send multipart/form-data with the zip in the field '{FIELD}'")
    too_large = HTTPException(413,
                              f"upload larger than the limit of {max_bytes} bytes")
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > max_bytes:
        raise too_large
    try:
        with dest.open("wb") as out:
            part = _BundlePart(out)
            parser = MultipartParser(options[b"boundary"], part.callbacks())
            received = 0
            async for chunk in request.stream():
                received += len(chunk)
                if on_bytes is not None:
                    on_bytes(len(chunk))
                if received > max_bytes:
                    raise too_large
                parser.write(chunk)
            parser.finalize()
    except FormParserError as exc:
        dest.unlink(missing_ok=True)
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"malformed multipart body: {exc}") from exc
    except BaseException:
        dest.unlink(missing_ok=True)
        raise
    if not part.seen or not part.finished:
        dest.unlink(missing_ok=True)
        detail = (f"multipart field '{FIELD}' (the journey zip) is missing" if not part.seen
                  else "multipart body ended early")
        raise HTTPException(422 if not part.seen
                            else status.HTTP_400_BAD_REQUEST, detail)
    return ReceivedFile(sha256=part.digest.hexdigest(), n_bytes=part.n_bytes)
