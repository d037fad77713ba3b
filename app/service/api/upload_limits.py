"""Uploads per key: how many and how many bytes one API key may upload in a sliding minute
(``SIGNMAP_UPLOAD_LIMIT_COUNT_PER_MIN``, ``SIGNMAP_UPLOAD_LIMIT_BYTES_PER_MIN``), counted in this
process's memory like ``auth.FailureThrottle`` (docs/decisions/upload-rate-limit.md says why).

An upload is admitted or refused before its body is read, and counts from then on, whatever the
answer turns out to be: checking a bundle costs the API CPU whether or not it is valid, so a flood
of broken uploads is limited like a flood of good ones."""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass

from fastapi import HTTPException, Request, status

WINDOW_S = 60.0
_make_lock = threading.Lock()


@dataclass
class _Upload:
    at: float
    n_bytes: int


@dataclass(frozen=True)
class Refusal:
    """Why an upload is refused now, and the whole seconds until it would be admitted."""

    reason: str
    retry_after_s: int


class UploadLimiter:
    """Each key's uploads of the last ``window_s`` (their times and bytes). ``admit`` refuses an
    upload while the key has made ``max_count`` uploads in the window, or when its bytes would go
    over ``max_bytes`` (0 = no limit, for either); an admitted upload counts at once and its bytes
    as they arrive (``received``). Keys are forgotten once their uploads expire, and at most
    ``max_keys`` are kept (the least recently uploading go first)."""

    def __init__(self, max_count: int, max_bytes: int, window_s: float = WINDOW_S,
                 max_keys: int = 100_000, clock=time.monotonic):
        self.max_count, self.max_bytes, self.window_s = max_count, max_bytes, window_s
        self.max_keys = max_keys
        self._clock = clock
        self._uploads: OrderedDict[str, deque[_Upload]] = OrderedDict()  # least recent first
        self._lock = threading.Lock()

    @property
    def enabled(self) -> bool:
        return self.max_count > 0 or self.max_bytes > 0

    def admit(self, key: str, declared_bytes: int = 0) -> tuple[_Upload | None, Refusal | None]:
        """(the upload's record, None) when ``key`` may upload now; (None, why not) otherwise.
        ``declared_bytes``: the body size the request announces (0 if it does not), so that an
        upload that would pass the byte limit is refused before it is read."""
        if not self.enabled:
            return None, None
        now = self._clock()
        with self._lock:
            self._forget_expired(now)
            uploads = self._uploads.get(key, deque())
            while uploads and now - uploads[0].at >= self.window_s:
                uploads.popleft()
            refusal = self._refusal(uploads, declared_bytes, now)
            if refusal is not None:
                return None, refusal
            upload = _Upload(now, 0)
            uploads.append(upload)
            self._uploads.pop(key, None)
            self._uploads[key] = uploads  # moved to the most recent end
            while len(self._uploads) > self.max_keys:
                self._uploads.popitem(last=False)
            return upload, None

    def received(self, upload: _Upload | None, n_bytes: int) -> None:
        """``n_bytes`` more of an admitted upload's body were read."""
        if upload is not None:
            with self._lock:
                upload.n_bytes += n_bytes

    def _refusal(self, uploads: deque[_Upload], declared_bytes: int, now: float) -> Refusal | None:
        live = list(uploads)  # the expired ones were dropped
        if self.max_count and len(live) >= self.max_count:
            wait = live[len(live) - self.max_count].at + self.window_s - now
            return Refusal(f"this key made {len(live)} uploads in the last {self.window_s:g} s, "
                           f"its limit is {self.max_count}", _whole(wait))
        used = sum(u.n_bytes for u in live)
        # An upload bigger than the whole budget is let through when the window is empty, or it
        # could never be made (the upload size limit bounds it on its own).
        if self.max_bytes and live and used + declared_bytes > self.max_bytes:
            # Wait until enough of the oldest uploads expire for this one to fit.
            freed, wait = 0, self.window_s
            for u in live:
                freed += u.n_bytes
                wait = u.at + self.window_s - now
                if used - freed + declared_bytes <= self.max_bytes:
                    break
            return Refusal(f"this key uploaded {used} bytes in the last {self.window_s:g} s"
                           + (f" and announces {declared_bytes} more" if declared_bytes else "")
                           + f", its limit is {self.max_bytes} bytes", _whole(wait))
        return None

    def _forget_expired(self, now: float) -> None:
        while self._uploads:
            key, uploads = next(iter(self._uploads.items()))
            if uploads and now - uploads[-1].at < self.window_s:
                break
            del self._uploads[key]


def _whole(seconds: float) -> int:
    return max(1, math.ceil(seconds))


def upload_limiter(request: Request) -> UploadLimiter:
    """The app's upload limiter (made at its first use, from the app's settings)."""
    state = request.app.state
    with _make_lock:
        if getattr(state, "upload_limiter", None) is None:
            settings = state.settings
            state.upload_limiter = UploadLimiter(settings.upload_limit_count_per_min,
                                                 settings.upload_limit_bytes_per_min)
        return state.upload_limiter


def admit_upload(request: Request, key: str) -> _Upload | None:
    """The upload's record for ``received``; 429 with Retry-After when ``key`` is over a limit."""
    declared = request.headers.get("content-length", "")
    limiter = upload_limiter(request)
    upload, refusal = limiter.admit(key, int(declared) if declared.isdigit() else 0)
    if refusal is not None:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            f"too many uploads: {refusal.reason}; upload again in {refusal.retry_after_s} s "
            "(Retry-After), or ask the operator to raise SIGNMAP_UPLOAD_LIMIT_COUNT_PER_MIN / "
            "SIGNMAP_UPLOAD_LIMIT_BYTES_PER_MIN",
            headers={"Retry-After": str(refusal.retry_after_s)})
    return upload
