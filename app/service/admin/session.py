"""Dashboard sign-in: an admin key posted once buys a session backed by its own short-lived admin
key (stored hashed like any other), carried in a signed, http-only, SameSite=strict cookie.

The session key is what the dashboard uses to call the public API on the operator's behalf, so the
operator's key is never stored anywhere; logging out or expiry deletes the session key's row.
"""

from __future__ import annotations

import os
import secrets
from datetime import timedelta
from pathlib import Path

from fastapi import Request
from itsdangerous import BadSignature, URLSafeTimedSerializer
from sqlalchemy import delete

from app.service.auth import create_key, key_sha256, lookup_key
from app.service.db import session_scope
from app.service.models import ApiKey, utc_now
from app.settings import Settings

COOKIE = "signmap_admin"
SESSION_KEY_PREFIX = "dashboard-session"


class NotSignedIn(Exception):
    """Raised by ``session_key``; the router turns it into a redirect to the sign-in page."""


def _secret(data_dir: Path) -> str:
    """The deployment's signing secret, created once under data_dir (shared by every API process)."""
    path = data_dir / "admin-session.secret"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:  # another process created it first
            pass
        else:
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32))
    return path.read_text().strip()


def _serializer(settings: Settings) -> URLSafeTimedSerializer:
    return URLSafeTimedSerializer(_secret(settings.data_dir), salt="signmap-admin-session")


def sign_in(settings: Settings, key: str) -> str | None:
    """The cookie value for a valid admin ``key``; None for an unknown or non-admin key."""
    with session_scope(settings.effective_database_url) as session:
        principal = lookup_key(session, key, settings.admin_key)
        if principal is None or principal.role != "admin":
            return None
        _forget_expired(session, settings.admin_session_max_age_s)
        session_key = create_key(session, "admin", f"{SESSION_KEY_PREFIX} of {principal.name}"[:200])
    return _serializer(settings).dumps(session_key)


def session_key(request: Request) -> str:
    """The signed-in session's own admin key; NotSignedIn without a valid, live session."""
    settings: Settings = request.app.state.settings
    raw = request.cookies.get(COOKIE)
    if not raw:
        raise NotSignedIn
    try:
        key = _serializer(settings).loads(raw, max_age=settings.admin_session_max_age_s)
    except BadSignature:
        raise NotSignedIn from None
    with session_scope(settings.effective_database_url) as session:
        principal = lookup_key(session, key, None)
    if principal is None or principal.role != "admin":  # signed out, expired or revoked
        raise NotSignedIn
    return key


def sign_out(settings: Settings, key: str) -> None:
    with session_scope(settings.effective_database_url) as session:
        session.execute(delete(ApiKey).where(ApiKey.key_sha256 == key_sha256(key)))


def _forget_expired(session, max_age_s: int) -> None:
    session.execute(delete(ApiKey).where(
        ApiKey.name.startswith(SESSION_KEY_PREFIX),
        ApiKey.created_at < utc_now() - timedelta(seconds=max_age_s)))


def cookie_args(request: Request, settings: Settings) -> dict:
    return dict(key=COOKIE, httponly=True, samesite="strict", path="/admin",
                secure=request.url.scheme == "https", max_age=settings.admin_session_max_age_s)
