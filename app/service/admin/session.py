"""Dashboard sign-in: an admin key posted once buys a session, carried in an http-only,
SameSite=strict cookie that holds only an opaque random token.

The server keeps the token's SHA-256 in ``admin_sessions`` with who signed in and when the session
expires, so the cookie is worth nothing elsewhere: it is not an API key (a Bearer request with it
gets 401), it stops working the moment it expires, and signing out deletes its row. Expired rows
are swept at every sign-in and by the API's periodic sweep (``app.service.jobs.sweep``).
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from datetime import timedelta

from fastapi import Request
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from app.service.auth import Principal, key_sha256, lookup_key
from app.service.db.crud import forget_expired
from app.service.db.models import AdminSessionRow, ApiKeyRow, utc_now
from app.service.deps import SessionDep, SettingsDep
from app.settings import Settings

COOKIE = "signmap_admin"


class NotSignedIn(Exception):
    """Raised by ``current_session``; the router turns it into a redirect to the sign-in page."""


@dataclass(frozen=True)
class DashboardSession:
    token_sha256: str
    principal: Principal


def sign_in(session: Session, settings: Settings, key: str) -> str | None:
    """The cookie value (a fresh opaque token) for a valid admin ``key``; None for an unknown or
    non-admin key (``auth.RevokedKey`` for a revoked one)."""
    token = secrets.token_urlsafe(32)
    principal = lookup_key(session, key, settings.admin_key)
    if principal is None or principal.role != "admin":
        return None
    forget_expired(session)
    now = utc_now()
    session.add(AdminSessionRow(token_sha256=key_sha256(token), key_id=principal.key_id,
                                name=principal.name[:200], created_at=now,
                                expires_at=now + timedelta(seconds=settings.admin_session_max_age_s)))
    return token


def current_session(request: Request, settings: SettingsDep, session: SessionDep
                    ) -> DashboardSession:
    """The signed-in session of this request; NotSignedIn without a valid, unexpired one."""
    token = request.cookies.get(COOKIE)
    if not token:
        raise NotSignedIn
    digest = key_sha256(token)
    row = session.execute(
        select(AdminSessionRow.key_id, AdminSessionRow.name, ApiKeyRow.role, ApiKeyRow.revoked_at)
        .outerjoin(ApiKeyRow, ApiKeyRow.id == AdminSessionRow.key_id)
        .where(AdminSessionRow.token_sha256 == digest, AdminSessionRow.expires_at > utc_now())
    ).first()
    session.commit()  # ends the lookup's read: a long page (a map read) holds no connection for it
    if row is None:  # unknown, signed out or expired
        raise NotSignedIn
    if row.key_id is None and not settings.admin_key:  # the environment's key was unset since
        raise NotSignedIn
    if row.key_id is not None and (row.role != "admin" or row.revoked_at is not None):
        raise NotSignedIn  # the key is gone, revoked (which deletes its sessions too) or not admin
    return DashboardSession(token_sha256=digest,
                            principal=Principal(key_id=row.key_id, role="admin", name=row.name))


def sign_out(session: Session, token_sha256: str) -> None:
    session.execute(delete(AdminSessionRow).where(AdminSessionRow.token_sha256 == token_sha256))


def cookie_args(request: Request, settings: Settings) -> dict:
    return dict(**_attributes(request), max_age=settings.admin_session_max_age_s)


def deletion_args(request: Request) -> dict:
    """``Response.delete_cookie``'s arguments: the cookie's own attributes, as its deletion
    would otherwise go out with Starlette's SameSite=lax."""
    return _attributes(request)


def _attributes(request: Request) -> dict:
    return dict(key=COOKIE, httponly=True, samesite="strict", path="/admin",
                secure=request.url.scheme == "https")
