"""Bearer-token check on writes: ``Authorization: Bearer <token>`` when a token is set.

The token comes from ``SSMPC_API_TOKEN`` (read when the app is built). The
comparison is constant-time (``hmac.compare_digest``) and the token is never
logged or echoed. A token that is set but empty (or only blanks) is a
configuration error, not "no token": it would silently switch the check off.

The guard returns the identity the request authenticated as, which the controller
records with the operator action (:mod:`services.events`): the api token is the
operator's (:data:`TOKEN_IDENTITY`, or the ``identity`` the guard is made with); an
api served without a token (loopback only) takes writes as :data:`ANONYMOUS`.
"""

from __future__ import annotations

import hmac
import os
from typing import Annotated

from fastapi import Header, HTTPException

__all__ = ["ENV", "ANONYMOUS", "TOKEN_IDENTITY", "check_token", "token_from_env",
           "make_write_guard"]

ENV = "SSMPC_API_TOKEN"
#: The identity of a request that presented the api token.
TOKEN_IDENTITY = "operator"
#: The identity of a write to an api that has no token (loopback only).
ANONYMOUS = "anonymous"


def check_token(token: str | None, where: str = "token") -> str | None:
    """``token`` as given; ValueError when it is set but empty or only blanks."""
    if token is not None and not token.strip():
        raise ValueError(f"{where}: set but empty; give a token, or unset it to serve "
                         "writes without one (loopback only)")
    return token


def token_from_env() -> str | None:
    """``SSMPC_API_TOKEN``, None when unset; ValueError when set but empty."""
    return check_token(os.environ.get(ENV), ENV)


def make_write_guard(token: str | None, identity: str = TOKEN_IDENTITY):
    """A FastAPI dependency that rejects writes without the right bearer token and
    returns the identity behind the request (``identity``; :data:`ANONYMOUS` when no
    token is set)."""
    check_token(token)
    if not identity or not identity.isprintable() or len(identity) > 128:
        raise ValueError(f"identity: expected 1..128 printable characters, got {identity!r}")
    expected = None if token is None else token.encode()

    def guard(authorization: Annotated[str | None, Header()] = None) -> str:
        if expected is None:
            return ANONYMOUS
        scheme, _, given = (authorization or "").partition(" ")
        if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(),
                                                                 expected):
            raise HTTPException(status_code=401, detail="missing or wrong bearer token",
                                headers={"WWW-Authenticate": "Bearer"})
        return identity

    return guard
