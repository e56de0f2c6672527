"""Bearer-token check on writes: ``Authorization: Bearer <token>`` when a token is set.

The token comes from ``SSMPC_API_TOKEN`` (read when the app is built). The
comparison is constant-time (``hmac.compare_digest``) and the token is never
logged or echoed. A token that is set but empty (or only blanks) is a
configuration error, not "no token": it would silently switch the check off.
"""

from __future__ import annotations

import hmac
import os
from typing import Annotated

from fastapi import Header, HTTPException

__all__ = ["ENV", "check_token", "token_from_env", "make_write_guard"]

ENV = "SSMPC_API_TOKEN"


def check_token(token: str | None, where: str = "token") -> str | None:
    """``token`` as given; ValueError when it is set but empty or only blanks."""
    if token is not None and not token.strip():
        raise ValueError(f"{where}: set but empty; give a token, or unset it to serve "
                         "writes without one (loopback only)")
    return token


def token_from_env() -> str | None:
    """``SSMPC_API_TOKEN``, None when unset; ValueError when set but empty."""
    return check_token(os.environ.get(ENV), ENV)


def make_write_guard(token: str | None):
    """A FastAPI dependency that rejects writes without the right bearer token."""
    check_token(token)
    expected = None if token is None else token.encode()

    def guard(authorization: Annotated[str | None, Header()] = None) -> None:
        if expected is None:
            return
        scheme, _, given = (authorization or "").partition(" ")
        if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(),
                                                                 expected):
            raise HTTPException(status_code=401, detail="missing or wrong bearer token",
                                headers={"WWW-Authenticate": "Bearer"})

    return guard
