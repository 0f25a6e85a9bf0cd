"""Who may open the viewer and what they may do: access tokens, roles, and a tolerant websocket reader.

    access = Access.for_host("0.0.0.0", share="view")      # tokens made with `secrets`
    with access.guard():                                     # around viser.ViserServer(...) only
        server = viser.ViserServer(host="0.0.0.0", port=8080)
    access.role(client)                                      # "control" or "view"

Rules (docs/viewer.md "Sharing on a network"):
- Bound to 127.0.0.1, ::1 or localhost with `--share control` (the default) and no `--token`:
  no token, everyone controls (as before tokens existed).
- Any other address, `--share view` or `--token`: every HTTP request and websocket handshake needs
  a token, given as `?token=...` in the URL (the page then keeps it in an HttpOnly cookie, which the
  browser sends with the page's assets and its websocket) or as that cookie. Without it the server
  answers 403 and the websocket is refused. With `--share control` the one token controls; with
  `--share view` the shared token opens a view-only page (no pause, export, refine, ...) and a second,
  control token (printed on the terminal only) opens the full page.

How it hooks into viser 1.1.1: viser serves its page and its websocket from one
`websockets.asyncio.server.serve(..., process_request=viser_http_server)` call, made on viser's
own thread while `ViserServer.__init__` runs, and exposes no hook for it. `guard()` replaces
`websockets.asyncio.server.serve` for the duration of that constructor (under a lock,
page_shim.serving) with a function that wraps viser's `process_request` in the token check (and
page_shim's page script); nothing else changes. The role of a
connected client is read from its handshake request (`ServerConnection.request`, public websockets
API) found through viser's `_live_connections`, filled before `on_client_connect` callbacks run.

`tolerate_malformed_messages()` swaps viser's websocket reader (`infra._infra._message_consumer`,
looked up by name on each connection) for one that drops a message it cannot decode instead of
closing the connection with an exception.
"""

from __future__ import annotations

import http
import ipaddress
import logging
import secrets
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger(__name__)

LOOPBACK_NAMES = ("127.0.0.1", "::1", "localhost")
SHARE_MODES = ("control", "view")
ROLES = ("control", "view")


def is_loopback_name(host: str) -> bool:
    """Only the three names the rules allow without a token (not 127.0.0.2 and the like)."""
    return host.strip("[]") in LOOPBACK_NAMES


def new_token() -> str:
    return secrets.token_urlsafe(18)


@dataclass
class Access:
    """Tokens of one viewer: token -> role. Empty: open to anyone who can reach it (loopback)."""

    tokens: dict
    share: str = "control"
    port: int | None = None

    @classmethod
    def for_host(cls, host: str, share: str = "control", token: str | None = None) -> "Access":
        if share not in SHARE_MODES:
            raise ValueError(f"share must be one of {SHARE_MODES}, not {share!r}")
        if token is not None and len(token) < 8:
            from splat_core.errors import InputError
            raise InputError("--token: use at least 8 characters (or leave it out for a generated one)")
        if is_loopback_name(host) and share == "control" and token is None:
            return cls({}, share)
        shared = token or new_token()
        tokens = {shared: share}
        if share == "view":
            tokens[new_token()] = "control"
        return cls(tokens, share)

    @property
    def required(self) -> bool:
        return bool(self.tokens)

    def token_for(self, role: str) -> str | None:
        return next((t for t, r in self.tokens.items() if r == role), None)

    def url(self, host: str, port: int, role: str | None = None) -> str:
        """The page's URL for `role` (the shared one by default), token included."""
        shown = f"[{host}]" if ":" in host and not host.startswith("[") else host
        base = f"http://{shown}:{port}/"
        token = self.token_for(role or self.share) if self.required else None
        return f"{base}?token={token}" if token else base

    # ------------------------------------------------------------------ requests
    @property
    def cookie_name(self) -> str:
        return f"splatam_token_{self.port}" if self.port else "splatam_token"

    def token_of(self, request) -> str | None:
        """The token a request carries: ?token= in its path, else the cookie."""
        query = parse_qs(urlsplit(request.path).query)
        if query.get("token"):
            return query["token"][0]
        for header in request.headers.get_all("Cookie"):
            for part in header.split(";"):
                name, _, value = part.strip().partition("=")
                if name == self.cookie_name:
                    return value
        return None

    def role_of_request(self, request) -> str | None:
        """"control" / "view", or None when the request may not in."""
        if not self.required:
            return "control"
        token = self.token_of(request)
        if token is None:
            return None
        for known, role in self.tokens.items():
            if secrets.compare_digest(token.encode(), known.encode()):
                return role
        return None

    def role(self, client) -> str:
        """The role of a connected viser client ("control" when no tokens are needed)."""
        if not self.required or client is None:
            return "control"
        try:   # viser keeps each client's websocket in _live_connections (see the module docstring)
            connection = client._viser_server._websock_server._live_connections.get(client.client_id)  # noqa: SLF001
        except AttributeError:
            connection = None
        request = getattr(connection, "request", None)
        return (self.role_of_request(request) if request is not None else None) or "view"

    def wrap(self, inner):
        """viser's process_request, behind the token check."""
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        def process_request(connection, request):
            role = self.role_of_request(request)
            if role is None:
                body = (b"splatam-viewer: this page needs its access token. Open the URL the viewer printed "
                        b"(it ends in ?token=...).\n")
                return Response(http.HTTPStatus.FORBIDDEN, "Forbidden",
                                Headers({"Content-Type": "text/plain; charset=utf-8",
                                         "Content-Length": str(len(body))}), body)
            response = inner(connection, request) if inner is not None else None
            token = parse_qs(urlsplit(request.path).query).get("token")
            if response is not None and token and self.required:
                response.headers["Set-Cookie"] = (f"{self.cookie_name}={token[0]}; Path=/; HttpOnly; "
                                                  "SameSite=Strict")
            return response
        return process_request

    def guard(self):
        """Around `viser.ViserServer(...)`: its HTTP and websocket server checks tokens (when
        required) and serves the page with page_shim's script (page_shim.serving does the hooking)."""
        from .page_shim import serving
        return serving(self.wrap) if self.required else serving()


def check_bind(host: str) -> None:
    """An address this machine can name; InputError otherwise (one line, no traceback)."""
    from splat_core.errors import InputError

    if host in ("localhost",):
        return
    try:
        ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        raise InputError(f"--host {host}: expected an IP address (127.0.0.1, 0.0.0.0, ::1, ...) or localhost")


def tolerate_malformed_messages() -> None:
    """Drop websocket messages that do not decode instead of closing the connection (idempotent)."""
    from viser.infra import _infra

    if getattr(_infra._message_consumer, "_tolerant", False):
        return

    async def _message_consumer(websocket, handle_message, message_class):
        while True:
            raw = await websocket.recv()
            try:
                if not isinstance(raw, bytes):
                    raise TypeError(f"text frame of {len(raw)} characters")
                message = message_class.deserialize(raw)
            except Exception as e:   # noqa: BLE001 - a bad message is dropped, the page stays connected
                log.warning("viewer: ignored a malformed websocket message (%s)", type(e).__name__)
                continue
            handle_message(message)
    _message_consumer._tolerant = True
    _infra._message_consumer = _message_consumer
