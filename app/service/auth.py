"""API keys: ``Authorization: Bearer <key>``; keys are stored as their SHA-256, never in clear.
Keys are created, listed and revoked here (``signmap keys`` and the dashboard call these), and
``FailureThrottle`` counts each client address's failed attempts. The request dependencies that
check keys are in ``app.service.deps``."""

from __future__ import annotations

import hashlib
import hmac
import math
import secrets
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import delete, or_, select, update
from sqlalchemy.orm import Session

from app.service.db.models import ROLES, AdminSessionRow, ApiKeyRow, utc_now

# A key's last_used_at is written when it is older than this: a busy key costs one write a minute,
# not one per request, and "last used" stays as precise as an operator needs.
LAST_USED_EVERY_S = 60.0


class UnknownKey(LookupError):
    """No stored key has this id."""


@dataclass(frozen=True)
class Principal:
    """Who is calling: ``key_id`` is None for the environment's admin key."""

    key_id: int | None
    role: str
    name: str

    def owns(self, owner_key_id: int | None) -> bool:
        return self.role == "admin" or (self.key_id is not None and self.key_id == owner_key_id)


def wrong_role_hint(role: str, roles: tuple[str, ...]) -> str:
    """What a key refused for its role (403) should use instead, to follow the refusal's detail;
    "" where the refusal says it all. A fleet key is refused the map by design
    (docs/decisions/fleet-key-map.md): its own journeys' signs are its to read, the map is not."""
    if role == "fleet" and "reader" in roles and "fleet" not in roles:
        return ("; a fleet key reads only its own journeys (a journey's signs: "
                "GET /api/v1/journeys/{id}/signs). To read the map, use a reader key: an operator "
                "makes one with `signmap keys create --role reader`")
    return ""


def key_sha256(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def create_key(session: Session, role: str, name: str = "") -> str:
    """Store a new key of ``role`` and return it in clear; this is the only time it is known."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}")
    key = secrets.token_urlsafe(32)
    session.add(ApiKeyRow(name=name, role=role, key_sha256=key_sha256(key)))
    session.flush()
    return key


class RevokedKey(Exception):
    """The key exists but was revoked (raised by ``lookup_key``: it answers 401 like an unknown
    key, but is no guess, so it does not count against the caller's address)."""


def lookup_key(session: Session, key: str, admin_key: str | None) -> Principal | None:
    """The principal of ``key``, None for an unknown one; RevokedKey for a revoked one. Marks a
    stored key used (in ``session``'s transaction: the caller commits) when its mark is stale."""
    if admin_key and hmac.compare_digest(key.encode(), admin_key.encode()):
        return Principal(key_id=None, role="admin", name="SIGNMAP_ADMIN_KEY")
    # Read on every request, never cached: a revoked key is refused by its very next request.
    row = session.execute(select(ApiKeyRow.id, ApiKeyRow.role, ApiKeyRow.name,
                                 ApiKeyRow.revoked_at, ApiKeyRow.last_used_at)
                          .where(ApiKeyRow.key_sha256 == key_sha256(key))).first()
    if row is None:
        return None
    if row.revoked_at is not None:
        raise RevokedKey(row.id)
    _mark_used(session, row.id, row.last_used_at)
    return Principal(key_id=row.id, role=row.role, name=row.name)


def _mark_used(session: Session, key_id: int, last_used_at: datetime | None) -> None:
    now = utc_now()
    stale = now - timedelta(seconds=LAST_USED_EVERY_S)
    if last_used_at is not None and last_used_at > stale:
        return  # the common case: no write at all
    # Conditional, so that concurrent requests of one key write it once.
    session.execute(update(ApiKeyRow)
                    .where(ApiKeyRow.id == key_id,
                           or_(ApiKeyRow.last_used_at.is_(None), ApiKeyRow.last_used_at <= stale))
                    .values(last_used_at=now))


def list_keys(session: Session) -> list[ApiKeyRow]:
    """Every stored key, revoked ones included, oldest first."""
    return list(session.scalars(select(ApiKeyRow).order_by(ApiKeyRow.id)))


def revoke_key(session: Session, key_id: int) -> tuple[ApiKeyRow, bool]:
    """Revoke key ``key_id`` and end its dashboard sessions; (its row, whether this call revoked
    it: False when it already was). UnknownKey when there is no such key."""
    row = session.get(ApiKeyRow, key_id)
    if row is None:
        raise UnknownKey(f"no key {key_id}")
    if row.revoked_at is not None:
        return row, False
    row.revoked_at = utc_now()
    session.execute(delete(AdminSessionRow).where(AdminSessionRow.key_id == key_id))
    session.flush()
    return row, True


class FailureThrottle:
    """Failed attempts per client address (wrong keys at the dashboard's sign-in, unknown Bearer
    keys), in this process's memory: after ``limit`` failures within ``window_s`` the address is
    refused until the oldest of them is ``window_s`` old. A refused attempt is not checked, so it
    neither counts nor extends the wait; a success clears nothing (else a valid key would buy
    unlimited guesses). Addresses are forgotten once their failures expire, and at most
    ``max_addresses`` are kept (the least recently failing go first)."""

    def __init__(self, limit: int, window_s: float, max_addresses: int = 100_000,
                 clock=time.monotonic):
        self.limit, self.window_s, self.max_addresses = limit, window_s, max_addresses
        self._clock = clock
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()  # least recent first
        self._lock = threading.Lock()

    def retry_after_s(self, address: str) -> int:
        """Seconds until ``address`` may try again (whole, rounded up); 0 when it may now."""
        now = self._clock()
        with self._lock:
            times = self._failures.get(address)
            if times is None or len(times) < self.limit:
                return 0
            wait = times[0] + self.window_s - now
        return max(1, math.ceil(wait)) if wait > 0 else 0

    def failed(self, address: str) -> bool:
        """Count a failure of ``address``; True when that one made it reach the limit."""
        now = self._clock()
        with self._lock:
            self._forget_expired(now)
            times = self._failures.pop(address, None) or deque(maxlen=self.limit)
            times.append(now)
            self._failures[address] = times  # moved to the most recent end
            while len(self._failures) > self.max_addresses:
                self._failures.popitem(last=False)
            return len(times) == self.limit and now - times[0] < self.window_s

    def _forget_expired(self, now: float) -> None:
        while self._failures:
            address, times = next(iter(self._failures.items()))
            if now - times[-1] < self.window_s:
                return
            del self._failures[address]
