"""Who and what may reach the web app: body size, Host and Origin, and the access token.

Three ASGI middlewares, outermost first in ``create_app``:

* :class:`BodyLimit`: 413 for a request body over 64 KiB, before anything reads it whole;
* :class:`SameOrigin`: the Host header must name an allowed host (DNS rebinding: 400), an
  Origin header must be the app's own origin, scheme, host and port (a page of any other
  origin, another port of this host included, on HTTP and websocket alike: 403), a
  request body must be ``application/json`` (a cross-site form or ``text/plain`` post:
  415), and no page of another origin may frame the app's (clickjacking);
* :class:`TokenGate`: with a token (required for a bind beyond loopback), every request,
  the 3D viewer's included, must carry it (401): ``Authorization: Bearer <token>``, the
  ``orbit_emulator_token`` cookie, or ``?token=<token>`` in the URL, which also sets the
  cookie, so that the page opened from the printed link can call the API and open the
  viewer's websocket.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import os
import re
import secrets
from urllib.parse import parse_qsl, urlencode

MAX_BODY_BYTES = 64 * 1024
"""Request bodies beyond this get 413 before anything reads them whole."""

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
ALLOWED_HOSTS_ENV = "ORBIT_EMULATOR_ALLOWED_HOSTS"
"""Comma-separated host names the server answers to beside loopback (and its bind host)."""
TOKEN_ENV = "ORBIT_EMULATOR_TOKEN"
"""The access token, where one is given rather than generated."""
TOKEN_COOKIE = "orbit_emulator_token"
MIN_TOKEN_CHARS = 16


class AccessError(ValueError):
    """A bind or token that would leave the arms open to anyone: the user's mistake."""


def is_loopback(host: str) -> bool:
    """Whether binding `host` keeps the server to this machine."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False  # a host name, or a wildcard such as 0.0.0.0: reachable from outside


def access_token(host: str, generate: bool = False) -> tuple[str | None, bool]:
    """(the token the server requires, whether it was generated now) for a bind on host.

    $ORBIT_EMULATOR_TOKEN if set (on any bind); otherwise, beyond loopback, a new random
    token with ``generate``, else AccessError; on loopback without one: no token."""
    given = os.environ.get(TOKEN_ENV)
    if given is not None:
        return check_token(given, TOKEN_ENV), False
    if is_loopback(host):
        return None, False
    if generate:
        return secrets.token_urlsafe(24), True
    raise AccessError(
        f"--host {host}: not a loopback address, so anyone who can reach it could drive the "
        f"arms; set {TOKEN_ENV} to a secret of at least {MIN_TOKEN_CHARS} characters, or pass "
        f"--generate-token to have one made and printed")


TOKEN_CHARS = re.compile(r"[A-Za-z0-9._~-]+")
"""What a token may hold: it travels in a URL and a cookie unchanged (`openssl rand -hex
16` or Python's secrets.token_urlsafe make such tokens)."""


def check_token(token: str, source: str = "token") -> str:
    if len(token) < MIN_TOKEN_CHARS or not TOKEN_CHARS.fullmatch(token):
        raise AccessError(f"{source}: at least {MIN_TOKEN_CHARS} characters, only letters, "
                          f"digits and . _ ~ - (e.g. openssl rand -hex 16)")
    return token


def allowed_hosts(bind_host: str) -> frozenset[str]:
    """The host names a request's Host and Origin may name: loopback, the address bound
    (unless a wildcard) and those in $ORBIT_EMULATOR_ALLOWED_HOSTS."""
    extra = [h.strip().lower() for h in os.environ.get(ALLOWED_HOSTS_ENV, "").split(",")]
    names = set(LOOPBACK_HOSTS) | {h for h in extra if h}
    if bind_host not in ("0.0.0.0", "::", ""):
        names.add(bind_host.lower().strip("[]"))
    return frozenset(names)


def _host_name(authority: str) -> str:
    """'example.org:8000' -> 'example.org', '[::1]:8000' -> '::1'."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1:].split("]", 1)[0]
    return authority.rsplit(":", 1)[0] if authority.count(":") == 1 else authority


async def _reject(scope, send, status: int, detail: str,
                  headers: tuple[tuple[bytes, bytes], ...] = ()) -> None:
    """An HTTP error answer, or for a websocket a refused handshake (HTTP 403)."""
    if scope["type"] == "websocket":
        await send({"type": "websocket.close", "code": 1008})
        return
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()), *headers]})
    await send({"type": "http.response.body", "body": body})


class BodyLimit:
    """413 for an HTTP request whose body exceeds ``limit`` bytes, by its Content-Length
    or, without one, once the chunks read pass it (a body within the limit is read here
    and handed on whole)."""

    def __init__(self, app, limit: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        too_big = f"request body over {self.limit // 1024} KiB"
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None:
            try:
                if int(declared) > self.limit:
                    return await _reject(scope, send, 413, too_big)
            except ValueError:
                pass
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                return
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            if size > self.limit:
                return await _reject(scope, send, 413, too_big)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: wait for a disconnect, as usual

        await self.app(scope, replay, send)


class SameOrigin:
    """Against DNS rebinding and requests from other origins (HTTP and websocket).

    The Host header must name an allowed host (400 otherwise): a page on a foreign name
    that resolves to this machine cannot reach the API. An Origin header, which browsers
    send with every cross-origin request, every POST and every websocket handshake, must
    be the app's own origin (403 otherwise): the scheme the request came in by, and the
    host and port of its Host header. Host names alone are not enough: a page served on
    another port of this host (any other local web service) is another origin, and
    SameSite cookies, the token's included, go along with its requests all the same.
    Without an Origin (API clients), a request that a browser marks as coming from another
    site (``Sec-Fetch-Site``) may only read (GET, HEAD), and the API only by a link the
    user follows (``Sec-Fetch-Mode: navigate``), not from a script, image or frame. A
    request with a body must declare ``application/json`` (415): a cross-site form or
    ``text/plain`` post, which browsers send without asking first, is refused.
    """

    def __init__(self, app, hosts: frozenset[str]) -> None:
        self.app = app
        self.hosts = hosts

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or ())
        host = headers.get(b"host", b"").decode("latin-1")
        if _host_name(host) not in self.hosts:
            return await _reject(scope, send, 400, f"host {host!r} is not allowed")
        origin = headers.get(b"origin")
        if origin is not None:
            text = origin.decode("latin-1")
            if _origin(text) != own_origin(scope.get("scheme", "http"), host):
                return await _reject(scope, send, 403, f"origin {text!r} is not allowed")
        elif _from_another_site(scope, headers):
            return await _reject(scope, send, 403, "a request from another site's page "
                                 "may not change anything")
        elif _api_call_from_another_site(scope, headers):
            return await _reject(scope, send, 403, "another site's page may link to the "
                                 "API, not call it")
        if scope["type"] == "http" and _has_body(headers):
            kind = headers.get(b"content-type", b"").split(b";")[0].strip().lower()
            if kind != b"application/json":
                return await _reject(scope, send, 415,
                                     "a request body must be application/json")
        if scope["type"] == "http":
            return await self.app(scope, receive, _not_framed(send))
        return await self.app(scope, receive, send)


NOT_FRAMED_HEADERS = ((b"x-frame-options", b"SAMEORIGIN"),
                      (b"content-security-policy", b"frame-ancestors 'self'"))
"""On every answer: only the app's own pages may frame its pages (the control page frames
the 3D viewer). A page of another origin that framed the app, another port of this host
included, could turn a click of the operator's into Start or Stop (clickjacking): the
origin check sees the framed page's own requests as the app's."""


def _not_framed(send):
    """``send``, adding :data:`NOT_FRAMED_HEADERS` to the response's headers."""

    async def sending(message):
        if message["type"] == "http.response.start":
            names = {name.lower() for name, _ in message.get("headers", ())}
            extra = [h for h in NOT_FRAMED_HEADERS if h[0] not in names]
            message = {**message, "headers": [*message.get("headers", ()), *extra]}
        await send(message)

    return sending


DEFAULT_PORTS = {"http": 80, "https": 443}


def own_origin(scheme: str, host: str) -> tuple[str, str, int]:
    """(scheme, host name, port) of the app as a request reached it: its scheme (ws and
    wss are http and https) and its Host header."""
    scheme = {"ws": "http", "wss": "https"}.get(scheme, scheme)
    return scheme, _host_name(host), _port_of(host, DEFAULT_PORTS.get(scheme, 0))


def _origin(text: str) -> tuple[str, str, int] | None:
    """An Origin header as (scheme, host name, port); None for "null" or anything not
    ``scheme://host[:port]``."""
    scheme, sep, authority = text.strip().lower().partition("://")
    if not sep or not authority or "/" in authority or scheme not in DEFAULT_PORTS:
        return None
    port = _port_of(authority, DEFAULT_PORTS[scheme])
    return (scheme, _host_name(authority), port) if port >= 0 else None


def _port_of(authority: str, default: int) -> int:
    """The port of 'host:port' or '[::1]:port' (default without one; -1 if not a port)."""
    authority = authority.strip()
    rest = authority.rsplit("]", 1)[1] if authority.startswith("[") else (
        authority if authority.count(":") == 1 else "")
    if ":" not in rest:
        return default
    digits = rest.rsplit(":", 1)[1]
    return int(digits) if digits.isascii() and digits.isdigit() and len(digits) <= 5 else -1


def _from_another_site(scope, headers: dict) -> bool:
    """A browser's request (Sec-Fetch-Site) from another origin that may change state:
    any method but GET and HEAD, and every websocket."""
    site = headers.get(b"sec-fetch-site", b"").strip().lower()
    if site not in (b"cross-site", b"same-site"):
        return False
    return scope["type"] == "websocket" or scope.get("method") not in ("GET", "HEAD")


def _api_call_from_another_site(scope, headers: dict) -> bool:
    """A script, image or frame of another site's page (Sec-Fetch-Site, and a fetch
    mode other than a top-level navigation) asking the API for anything: the browser
    would not let that page read the answer, but the app would still build it (a CSV, a
    zip, a bag, a forecast: seconds of CPU each), so a page could keep the machine busy
    by embedding links. A link the user follows (a navigation) is served."""
    site = headers.get(b"sec-fetch-site", b"").strip().lower()
    mode = headers.get(b"sec-fetch-mode", b"").strip().lower()
    return (site in (b"cross-site", b"same-site") and mode != b"navigate"
            and scope.get("path", "").startswith("/api/"))


def _cookies(headers: dict, name: str) -> list[str]:
    """The values of every cookie called `name` in the Cookie header, read leniently: a
    cookie of another app that a strict parser would reject does not hide this one."""
    values = []
    for part in headers.get(b"cookie", b"").decode("latin-1").split(";"):
        key, sep, value = part.strip().partition("=")
        if sep and key == name:
            values.append(value.strip().strip('"'))
    return values


def _has_body(headers: dict) -> bool:
    length = headers.get(b"content-length")
    if length is not None:
        return length.strip() not in (b"0", b"")
    return b"transfer-encoding" in headers


class TokenGate:
    """Every HTTP request and websocket must carry the token (401 / refused handshake).

    Accepted as ``Authorization: Bearer <token>``, the ``orbit_emulator_token`` cookie, or
    ``?token=<token>``; a valid ``?token=`` on an HTTP request sets the cookie (HttpOnly,
    SameSite=Strict), so the page opened from the printed link works on without it.
    Compared in constant time.
    """

    def __init__(self, app, token: str) -> None:
        self.app = app
        self.token = token.encode()

    def _valid(self, candidate: str | bytes | None) -> bool:
        if candidate is None:
            return False
        if isinstance(candidate, str):
            candidate = candidate.encode("utf-8", "replace")
        return hmac.compare_digest(candidate, self.token)

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or ())
        auth = headers.get(b"authorization", b"")
        if auth[:7].lower() == b"bearer " and self._valid(auth[7:].strip()):
            return await self.app(scope, receive, send)
        if any(self._valid(value) for value in _cookies(headers, TOKEN_COOKIE)):
            return await self.app(scope, receive, send)
        query = parse_qsl(scope.get("query_string", b"").decode("latin-1"))
        if any(name == "token" and self._valid(value) for name, value in query):
            if scope["type"] == "websocket":
                return await self.app(scope, receive, send)
            if b"text/html" in headers.get(b"accept", b""):  # a browser opening the link
                return await self._to_page_without_token(scope, send, query)
            return await self.app(scope, receive, self._setting_cookie(send))
        return await _reject(scope, send, 401,
                             "a token is required: Authorization: Bearer <token>, or open the "
                             "link the server printed (…/?token=<token>)",
                             headers=((b"www-authenticate", b"Bearer"),))

    async def _to_page_without_token(self, scope, send, query) -> None:
        """303 to the same page without the token in its URL (nor in the browser's
        history), with the cookie that carries it from now on."""
        rest = urlencode([(k, v) for k, v in query if k != "token"])
        location = (scope.get("root_path", "") + scope["path"] + (f"?{rest}" if rest else ""))
        await send({"type": "http.response.start", "status": 303,
                    "headers": [(b"location", location.encode("latin-1")),
                                (b"set-cookie", self._cookie()), (b"content-length", b"0")]})
        await send({"type": "http.response.body", "body": b""})

    def _cookie(self) -> bytes:
        return (f"{TOKEN_COOKIE}={self.token.decode()}; Path=/; HttpOnly; "
                f"SameSite=Strict").encode()

    def _setting_cookie(self, send):
        value = self._cookie()

        async def wrapped(message):
            if message["type"] == "http.response.start":
                message = {**message,
                           "headers": [*message.get("headers", []), (b"set-cookie", value)]}
            await send(message)

        return wrapped
