"""A Content-Security-Policy on the OpenAPI pages (``/docs``, ``/redoc``): the browser
may load nothing but what this server serves.

The pages' scripts and styles come from the ``fastapi-offline`` package through this
server, but a bundle can still reach out on its own: ReDoc 2's side menu shows the
Redocly logo from its CDN (``cdn.redoc.ly/redoc/logo-mini.svg``, unconditionally).
The policy (W3C CSP Level 3) stops such a request before it is made; a headless
Chromium that loaded both pages with it sent no request off this host, and both
rendered (the Redocly logo missing). Only the answers to the pages' own paths get
the header; every other request passes through untouched (a plain ASGI wrapper, no
per-request middleware cost on the REST routes).
"""

from __future__ import annotations

__all__ = ["DOCS_CSP", "DocsPolicy"]

#: Same-origin only; inline script and style as Swagger UI's page and ReDoc's
#: styled components need them; ReDoc's search worker is made from a blob.
DOCS_CSP = ("default-src 'none'; script-src 'self' 'unsafe-inline'; "
            "style-src 'self' 'unsafe-inline'; img-src 'self' data:; font-src 'self' data:; "
            "connect-src 'self'; worker-src 'self' blob:; base-uri 'none'; "
            "form-action 'none'; frame-ancestors 'none'")


class DocsPolicy:
    """ASGI wrapper: ``Content-Security-Policy: DOCS_CSP`` on the answers for ``paths``.

    Parameters
    ----------
    app : ASGI application
    paths : iterable of str
        Exact request paths of the pages (e.g. ``/docs``, ``/redoc``).
    """

    def __init__(self, app, paths) -> None:
        self.app = app
        self.paths = frozenset(paths)
        self._header = (b"content-security-policy", DOCS_CSP.encode("ascii"))

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope.get("path") not in self.paths:
            return await self.app(scope, receive, send)

        async def send_with_policy(message):
            if message["type"] == "http.response.start":
                headers = [h for h in message.get("headers", [])
                           if h[0].lower() != self._header[0]]
                message = {**message, "headers": [*headers, self._header]}
            await send(message)

        return await self.app(scope, receive, send_with_policy)
