"""The viewer's websocket handshake check: the same Host/Origin rules as the API's requests
(``console.security``). A Host header that is not a name of this console (DNS rebinding) or an
Origin that is not the viewer itself (a page elsewhere opening a websocket to 127.0.0.1) gets the
connection closed before anything is sent.

viser offers no public hook that sees the request's headers, so this one sits on its private
websocket server (``_websock_server``: its connect hook is awaited before anything is streamed,
and ``_live_connections`` holds the request). A viser upgrade that renames them is caught by the
viewer tests that connect with foreign names (tests/unit/console/test_console_viewer.py).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from console.security import host_allowed, origin_allowed

logger = logging.getLogger(__name__)


class HandshakeGuard:
    """Closes every websocket whose Host or Origin is not this viewer's; counts them."""

    def __init__(self, allowed_hosts: Sequence[str]) -> None:
        self._allowed_hosts = tuple(allowed_hosts)
        self._server: Any = None
        self.n_rejected = 0

    def install(self, server: Any) -> None:
        """Hook into ``server`` (a ``viser.ViserServer``): call before any client can have
        finished its handshake, i.e. right after the server is created."""
        self._server = server
        server._websock_server.on_client_connect(self._check)

    async def _check(self, conn: Any) -> None:
        """viser's websocket-level connect hook (awaited before anything is streamed)."""
        ws = self._server._websock_server._live_connections.get(conn.client_id)
        if ws is None:
            return
        headers = ws.request.headers
        # get_all, not get: get raises on a repeated header. Two Hosts (or Origins) are refused:
        # which one a check read would decide, and a browser never sends two.
        hosts, origins = headers.get_all("Host"), headers.get_all("Origin")
        host = hosts[0] if len(hosts) == 1 else None
        origin = origins[0] if origins else None
        # viser serves plain http: a page's Origin is http://<the Host>
        if host_allowed(host, self._allowed_hosts) and len(origins) <= 1 and origin_allowed(origin, host, "http"):
            return
        self.n_rejected += 1
        logger.warning("viewer: refused a connection with Host %r and Origin %r", hosts, origins)
        await ws.close(1008, "this viewer is not reachable by that name")
