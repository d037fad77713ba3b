"""Security headers on every dashboard response (pages, their errors and redirects, static files).

The pages load only their own scripts and styles (``/admin/static/...``: the app's, Leaflet's from
xstatic, VectorGrid's vendored copy) and fetch only their own JSON and vector tiles, so the policy
admits ``'self'`` and, for images, the base-map tile server (``map_tile_url``) and ``data:`` (the
blank image Leaflet puts in place of a tile it drops). No inline script runs: a page's data is a
``<script type="application/json">`` block, which is read, not run. Style *attributes* are
allowed (``style-src-attr``), for the server-drawn progress bars; style elements and sheets are
not.

An error no handler answers gets its 500 from ``app.service.app._JsonErrors``, outside this
middleware: a JSON body, without these headers, which guard pages.
"""

from __future__ import annotations

from urllib.parse import urlsplit

PREFIX = "/admin"


def tile_source(tile_url: str) -> str:
    """The CSP source of the base map's tiles: ``https://tile.example.org``; ``*.example.org``
    for a ``{s}.example.org`` subdomain template; "" for tiles on the dashboard's own origin."""
    parts = urlsplit(tile_url)
    if not parts.scheme or not parts.netloc:
        return ""  # a path on this origin: 'self'
    host = parts.netloc.rpartition("@")[2]  # a source cannot carry user:password
    if host.startswith("{s}."):
        host = "*." + host[len("{s}."):]
    if "{" in host:  # a template CSP cannot spell (tiles-{s}.example.org): the whole scheme
        return f"{parts.scheme}:"
    return f"{parts.scheme}://{host}"


def content_security_policy(tile_url: str) -> str:
    tiles = tile_source(tile_url)
    return "; ".join([
        "default-src 'self'",
        "script-src 'self'",
        "style-src 'self'",
        "style-src-attr 'unsafe-inline'",
        "img-src 'self' data:" + (f" {tiles}" if tiles else ""),
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    ])


class AdminHeaders:
    """ASGI middleware adding the headers to every response under /admin, whichever part of the app
    answered it (a route, an error handler, the static files, the router's 404)."""

    def __init__(self, app, tile_url: str):
        self.app = app
        headers = {
            "Content-Security-Policy": content_security_policy(tile_url),
            "X-Frame-Options": "DENY",  # frame-ancestors for browsers without CSP 2
            "X-Content-Type-Options": "nosniff",
            # Full URLs to the dashboard itself (a retry returns to the page it came from) and
            # the origin only to the tile server, whose usage policy wants a Referer.
            "Referrer-Policy": "strict-origin-when-cross-origin",
        }
        self.headers = [(name.lower().encode("latin-1"), value.encode("latin-1"))
                        for name, value in headers.items()]

    async def __call__(self, scope, receive, send):
        path = scope.get("path", "") if scope["type"] == "http" else ""
        if path != PREFIX and not path.startswith(PREFIX + "/"):
            return await self.app(scope, receive, send)

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                names = {name.lower() for name, _ in message.get("headers", [])}
                message["headers"] = [*message.get("headers", []),
                                      *(h for h in self.headers if h[0] not in names)]
            await send(message)

        await self.app(scope, receive, send_with_headers)
