"""Bearer-token check on writes: ``Authorization: Bearer <token>`` when a token is set.

The token comes from ``SSMPC_API_TOKEN`` (read when the app is built). The
comparison is constant-time (``hmac.compare_digest``) and the token is never
logged or echoed.
"""

from __future__ import annotations

import hmac
import os
from typing import Annotated

from fastapi import Header, HTTPException

__all__ = ["token_from_env", "make_write_guard"]

ENV = "SSMPC_API_TOKEN"


def token_from_env() -> str | None:
    token = os.environ.get(ENV, "")
    return token or None


def make_write_guard(token: str | None):
    """A FastAPI dependency that rejects writes without the right bearer token."""
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
