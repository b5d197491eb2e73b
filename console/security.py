"""Request guards: the run token, a same-origin check and a request-size limit.

* Token. Bound to loopback, only this machine's users can reach the console, and no
  token is needed. Bound to any other address, every request that can start or stop
  a run must carry the token (``Authorization: Bearer <token>``, ``X-Imgnav-Token``, or
  the form field ``token``). The token is generated at start (and printed) unless
  configured.
* Origin. No CORS headers are ever sent, so other sites cannot read answers; but a
  browser still *sends* a cross-site form POST. State-changing requests whose
  ``Origin`` is not this server are refused (403), which stops a web page elsewhere
  from starting the robot through a visitor's browser.
* Size. Bodies over ``max_bytes`` get 413 before they are read (Content-Length) or as
  soon as the count passes the limit (chunked uploads).
* Host. A loopback service is otherwise open to DNS rebinding: a web page whose domain
  is re-pointed at 127.0.0.1 is "same origin" with the console as far as the browser
  knows, and could start the robot. The ``Host`` header must therefore name this
  console as it is really reachable (``allowed_hosts``); Starlette's
  ``TrustedHostMiddleware`` answers 400 otherwise. The viewer's port applies the same
  names (``console.viewer``).
"""

from __future__ import annotations

import fcntl
import hmac
import ipaddress
import json
import logging
import secrets
import socket
import struct
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any
from urllib.parse import urlsplit

from console.words import size_words

logger = logging.getLogger(__name__)

# ASGI's callables, as Starlette types them (starlette.types), so the middleware composes with its own
Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]


def is_loopback(host: str) -> bool:
    if host in ("localhost", ""):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")
WILDCARD_BINDS = ("0.0.0.0", "::", "")
_SIOCGIFADDR = 0x8915  # Linux ioctl: an interface's IPv4 address


def interface_addresses() -> list[str]:
    """This machine's non-loopback IPv4 addresses, one per interface that has one.

    ``getaddrinfo(gethostname())`` is not enough: on Debian the host name resolves to
    127.0.1.1, which a phone cannot open. Linux answers per interface (ioctl); elsewhere
    the address of the default route is the best guess (a UDP connect sends nothing)."""
    found: list[str] = []
    try:
        names = [name for _, name in socket.if_nameindex()]
    except OSError:
        names = []
    for name in names:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                packed = fcntl.ioctl(s.fileno(), _SIOCGIFADDR, struct.pack("256s", name.encode()[:15]))
            except OSError:  # no IPv4 address on this interface
                continue
        addr = socket.inet_ntoa(packed[20:24])
        if not addr.startswith("127.") and addr not in found:
            found.append(addr)
    if not found:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.connect(("192.0.2.1", 9))  # TEST-NET-1: only picks the route, sends nothing
                addr = s.getsockname()[0]
                if not addr.startswith("127."):
                    found.append(addr)
            except OSError:
                pass
    return found


def _host_name(host: str) -> str:
    """A bind address or name as it appears in a Host header (IPv6 literals in brackets)."""
    host = host.strip().lower()
    try:
        if ipaddress.ip_address(host.strip("[]")).version == 6:
            return f"[{host.strip('[]')}]"
    except ValueError:
        pass
    return host


def allowed_hosts(bind_host: str, extra: tuple[str, ...] | list[str] = ()) -> list[str]:
    """The names the console is really reachable by, for the Host check.

    Loopback names always; the bind address itself; bound to every interface
    (0.0.0.0 / ::), this machine's addresses and names (``name``, ``name.local`` for
    mDNS, the FQDN); plus ``extra`` (``--allowed-host``: a reverse proxy's name, a DNS
    name on the LAN). Ports are not compared: the socket already fixed the port."""
    names: list[str] = list(LOOPBACK_NAMES)
    if bind_host not in WILDCARD_BINDS:
        names.append(_host_name(bind_host))
    else:
        names += interface_addresses()
        hostname = socket.gethostname().lower()
        if hostname:
            names += [hostname, f"{hostname}.local"]
        try:
            fqdn = socket.getfqdn().lower()
        except OSError:
            fqdn = ""
        if fqdn and fqdn != "localhost":
            names.append(fqdn)
    names += [_host_name(h) for h in extra if h.strip()]
    out: list[str] = []
    for n in names:
        if n and n not in out:
            out.append(n)
    return out


def host_of(host_header: str) -> str | None:
    """The host part of a Host header (brackets kept for IPv6), lower case; None if malformed."""
    text = host_header.strip().lower()
    if not text:
        return None
    if text.startswith("["):
        end = text.find("]")
        if end < 0 or (len(text) > end + 1 and not text[end + 1 :].startswith(":")):
            return None
        return text[: end + 1]
    host, _, port = text.partition(":")
    if port and not port.isdigit():
        return None
    return host or None


def host_allowed(host_header: str | None, allowed: list[str] | tuple[str, ...]) -> bool:
    """The same rule as Starlette's TrustedHostMiddleware (exact names, ``*.domain``)."""
    host = host_of(host_header or "")
    if host is None:
        return False
    for pattern in allowed:
        if host == pattern or (pattern.startswith("*.") and host.endswith(pattern[1:])):
            return True
    return "*" in allowed


def origin_allowed(origin: str | None, host_header: str | None, scheme: str = "http") -> bool:
    """A request without Origin (curl, same-origin GET) passes; otherwise the Origin must be
    this very server: the scheme it is served by (``scheme``: http, or https behind TLS; ws and
    wss count as http and https), the host and port of the Host header."""
    if origin is None:
        return True
    if origin == "null":
        return False
    return _same_origin(origin, host_header or "", scheme)


def new_token() -> str:
    return secrets.token_urlsafe(18)


def token_matches(expected: str | None, given: str | None) -> bool:
    if expected is None:
        return True
    if not given:
        return False
    return hmac.compare_digest(expected.encode(), given.strip().encode())


def token_from_headers(headers: Any) -> str | None:
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return headers.get("x-imgnav-token")


async def _send_json(send: Send, status: int, detail: dict[str, str]) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())],
        }
    )
    await send({"type": "http.response.body", "body": body})


class _TooLarge(Exception):
    pass


class GuardMiddleware:
    """Pure ASGI middleware: size limit, same-origin check on unsafe methods, security headers."""

    def __init__(self, app: Callable, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers: dict[str, str] = {}
        for k, v in scope.get("headers", []):
            name = k.decode("latin-1").lower()
            if name in ("host", "origin") and name in headers:
                # two Hosts (or Origins): which one a check reads would decide; a browser never sends two
                await _send_json(send, 400, {"code": "duplicate_header", "message": f"more than one {name} header"})
                return
            headers[name] = v.decode("latin-1")
        method = scope.get("method", "GET")
        if method not in ("GET", "HEAD", "OPTIONS"):
            origin = headers.get("origin")
            if (
                origin
                and origin != "null"
                and not _same_origin(origin, headers.get("host", ""), scope.get("scheme", "http"))
            ):
                await _send_json(
                    send, 403, {"code": "cross_origin", "message": f"requests from {origin} are not allowed"}
                )
                return
            if origin == "null":
                await _send_json(
                    send, 403, {"code": "cross_origin", "message": "opaque-origin requests are not allowed"}
                )
                return
        if method == "OPTIONS":  # no CORS: pre-flights get nothing that would allow a request
            await _send_json(send, 405, {"code": "no_cors", "message": "cross-origin requests are not supported"})
            return
        length = headers.get("content-length")
        if length is not None:
            try:
                declared = int(length)
            except ValueError:
                await _send_json(send, 400, {"code": "bad_length", "message": "invalid Content-Length"})
                return
            if declared > self.max_bytes:
                await _send_json(
                    send,
                    413,
                    {
                        "code": "request_too_large",
                        "message": f"the request is {size_words(declared)}; the limit is {size_words(self.max_bytes)}",
                    },
                )
                return
        received = 0
        overflow = False
        answered = False
        too_large = {
            "code": "request_too_large",
            "message": f"the request is over the limit of {size_words(self.max_bytes)}",
        }

        async def limited_receive() -> MutableMapping[str, Any]:
            nonlocal received, overflow
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    overflow = True
                    raise _TooLarge()
            return message

        async def guarded_send(message: MutableMapping[str, Any]) -> None:
            nonlocal answered
            if overflow:
                # The app's own answer to the aborted read (a 400 or 500) is replaced by a 413.
                if not answered:
                    answered = True
                    await _send_json(send, 413, too_large)
                return
            if message["type"] == "http.response.start":
                answered = True
                extra = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer")]
                message = {**message, "headers": list(message.get("headers", [])) + extra}
            await send(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except _TooLarge:
            if not answered:
                await _send_json(send, 413, too_large)


def _same_origin(origin: str, host_header: str, scheme: str = "http") -> bool:
    """``origin`` names this server: its scheme (``https://127.0.0.1:8000`` is another origin than
    ``http://127.0.0.1:8000``: a page served elsewhere over TLS under the same name), host and port."""
    parts = urlsplit(origin)
    served = {"ws": "http", "wss": "https"}.get(scheme, scheme)
    if parts.scheme != served or not parts.netloc:
        return False
    return parts.netloc.lower() == host_header.lower()
