"""FastAPI dependencies shared by the routes: the settings, the request's database session and the
calling principal (``Fleet``, ``Reader``, ``Admin``: a valid API key whose role may make the call).
"""

from __future__ import annotations

from typing import Annotated, Callable, Iterator

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from app.service.auth import Principal, lookup_key
from app.service.db.session import new_session
from app.settings import Settings

_bearer = HTTPBearer(auto_error=False, description="an API key from `signmap keys create`")


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


def current_principal(settings: SettingsDep, session: SessionDep,
                      credentials: Annotated[HTTPAuthorizationCredentials | None,
                                             Depends(_bearer)]) -> Principal:
    """Who calls: 401 without a valid ``Authorization: Bearer <key>``."""
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer API key",
                            headers={"WWW-Authenticate": "Bearer"})
    principal = lookup_key(session, credentials.credentials, settings.admin_key)
    session.commit()  # ends the lookup's read: a long route (a map read) holds no connection for it
    if principal is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "unknown API key",
                            headers={"WWW-Authenticate": "Bearer"})
    return principal


def require(*roles: str) -> Callable[..., Principal]:
    """A dependency admitting ``roles`` (and admin): 401 without a valid key, 403 otherwise."""

    def dependency(principal: Annotated[Principal, Depends(current_principal)]) -> Principal:
        if principal.role != "admin" and principal.role not in roles:
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"this call needs a {' or '.join(roles + ('admin',))} key, "
                                f"not {principal.role}")
        return principal

    return dependency


Fleet = Annotated[Principal, Depends(require("fleet"))]
Reader = Annotated[Principal, Depends(require("reader"))]
Admin = Annotated[Principal, Depends(require("admin"))]
