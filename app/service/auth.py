"""API keys: ``Authorization: Bearer <key>``; keys are stored as their SHA-256, never in clear.
The request dependencies that check them are in ``app.service.deps``."""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.service.db.models import ROLES, ApiKeyRow


@dataclass(frozen=True)
class Principal:
    """Who is calling: ``key_id`` is None for the environment's admin key."""

    key_id: int | None
    role: str
    name: str

    def owns(self, owner_key_id: int | None) -> bool:
        return self.role == "admin" or (self.key_id is not None and self.key_id == owner_key_id)


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


def lookup_key(session: Session, key: str, admin_key: str | None) -> Principal | None:
    if admin_key and hmac.compare_digest(key.encode(), admin_key.encode()):
        return Principal(key_id=None, role="admin", name="SIGNMAP_ADMIN_KEY")
    row = session.scalars(select(ApiKeyRow).where(ApiKeyRow.key_sha256 == key_sha256(key))).first()
    return None if row is None else Principal(key_id=row.id, role=row.role, name=row.name)
