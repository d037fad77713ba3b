"""FastAPI dependencies shared by the routes: the settings, the request's database session and the
calling principal (``Fleet``, ``Reader``, ``Admin``: a valid API key whose role may make the call).
"""

from __future__ import annotations

import logging
import threading
from typing import Annotated, Callable, Iterator

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.service.auth import (FailureThrottle, Principal, RevokedKey, lookup_key,
                              wrong_role_hint)
from app.service.db.session import new_session
from app.settings import Settings

log = logging.getLogger(__name__)
_bearer = HTTPBearer(auto_error=False, description="an API key from `signmap keys create`")
_throttle_lock = threading.Lock()


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_session(settings: SettingsDep) -> Iterator[Session]:
    """The request's session: committed when the route returns, rolled back when it raises. A route
    that must publish a write before it answers (a queued job reads it) commits it itself."""
    session = new_session(settings.effective_database_url)
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


# scope="function": the commit happens before the response is sent, not after.
SessionDep = Annotated[Session, Depends(get_session, scope="function")]


def auth_throttle(request: Request) -> FailureThrottle:
    """The app's count of failed key attempts per client address (made at its first use)."""
    state = request.app.state
    with _throttle_lock:
        if getattr(state, "auth_throttle", None) is None:
            settings: Settings = state.settings
            state.auth_throttle = FailureThrottle(settings.auth_failure_limit,
                                                  settings.auth_failure_window_s)
        return state.auth_throttle


def client_address(request: Request) -> str:
    # Behind a reverse proxy this is the proxy's address unless uvicorn trusts its
    # X-Forwarded-For (docs/service.md, "Keys and roles").
    return request.client.host if request.client else "?"


def refuse_if_throttled(request: Request) -> None:
    """429 with Retry-After while the caller's address has used up its failed attempts."""
    wait_s = auth_throttle(request).retry_after_s(client_address(request))
    if wait_s:
        raise HTTPException(status.HTTP_429_TOO_MANY_REQUESTS,
                            f"too many failed keys from this address; try again in {wait_s} s",
                            headers={"Retry-After": str(wait_s)})


def count_failure(request: Request, what: str) -> None:
    address = client_address(request)
    if auth_throttle(request).failed(address):
        settings: Settings = request.app.state.settings
        log.warning("%s from %s: %d failures in %g s, refused with 429 for a while", what,
                    address, settings.auth_failure_limit, settings.auth_failure_window_s)


def current_principal(request: Request, settings: SettingsDep, session: SessionDep,
                      credentials: Annotated[HTTPAuthorizationCredentials | None,
                                             Depends(_bearer)]) -> Principal:
    """Who calls: 401 without a valid ``Authorization: Bearer <key>``; 429 from an address that
    sent too many unknown keys (even with a valid key: a guess that hit would pass otherwise)."""
    refuse_if_throttled(request)
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer API key",
                            headers={"WWW-Authenticate": "Bearer"})
    try:
        principal = lookup_key(session, credentials.credentials, settings.admin_key)
    except RevokedKey:
        session.rollback()
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "this API key was revoked",
                            headers={"WWW-Authenticate": "Bearer"}) from None
    try:
        session.commit()  # ends the lookup (a long route holds no connection for it); last-used
    except OperationalError as exc:
        # Only the last-used mark was written: a database refusing writes still serves reads.
        session.rollback()
        log.warning("key %s: last use not recorded: %s", principal and principal.key_id, exc)
    if principal is None:
        count_failure(request, "unknown API key")
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "unknown API key",
                            headers={"WWW-Authenticate": "Bearer"})
    return principal


def _roles_phrase(roles: tuple[str, ...]) -> str:
    """"a fleet or admin key", "an admin key": each role once (admin may always), with its
    article."""
    names = list(dict.fromkeys((*roles, "admin")))
    article = "an" if names[0][0] in "aeiou" else "a"
    return f"{article} {' or '.join(names)} key"


def require(*roles: str) -> Callable[..., Principal]:
    """A dependency admitting ``roles`` (and admin): 401 without a valid key, 403 otherwise."""

    def dependency(principal: Annotated[Principal, Depends(current_principal)]) -> Principal:
        if principal.role != "admin" and principal.role not in roles:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"this call needs {_roles_phrase(roles)}, not {principal.role}"
                                + wrong_role_hint(principal.role, roles))
        return principal

    return dependency


Fleet = Annotated[Principal, Depends(require("fleet"))]
Reader = Annotated[Principal, Depends(require("reader"))]
Admin = Annotated[Principal, Depends(require("admin"))]
