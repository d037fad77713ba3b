"""API keys: ``Authorization: Bearer <key>``; keys are stored as their SHA-256, never in clear."""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass
from typing import Callable

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.service.db.session import session_scope
from app.service.db.models import ROLES, ApiKeyRow

# The ASGI scope key under which the dashboard's in-process API calls carry their principal.
DASHBOARD_PRINCIPAL = "signmap.dashboard_principal"
_bearer = HTTPBearer(auto_error=False, description="an API key from `signmap keys create`")


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


def require(*roles: str) -> Callable[..., Principal]:
    """A FastAPI dependency admitting ``roles`` (and admin): 401 without a valid key, 403 otherwise."""

    def dependency(request: Request,
                   credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> Principal:
        # The dashboard's in-process calls (admin.session.as_principal); HTTP cannot set this.
        principal = request.scope.get(DASHBOARD_PRINCIPAL)
        if principal is not None:
            return principal
        if credentials is None or credentials.scheme.lower() != "bearer":
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer API key",
                                headers={"WWW-Authenticate": "Bearer"})
        settings = request.app.state.settings
        with session_scope(settings.effective_database_url) as session:
            principal = lookup_key(session, credentials.credentials, settings.admin_key)
        if principal is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "unknown API key",
                                headers={"WWW-Authenticate": "Bearer"})
        if principal.role != "admin" and principal.role not in roles:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"this call needs a {' or '.join(roles + ('admin',))} key, "
                                f"not {principal.role}")
        return principal

    return dependency
