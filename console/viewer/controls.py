"""Each browser's own stop control in the viewer (token box, Stop button, note).

viser's GUI state is shared by every client unless it is created per client, so the stop control
is built for each client in its ``on_client_connect`` handler: a token typed by one client is
never sent to another, the box is masked (viser's text input has no password type) and cleared
after each use.
"""

from __future__ import annotations

import hmac
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class ClientControls:
    """One browser's stop control (never shared with other clients)."""

    token_box: Any | None
    stop_button: Any
    note: Any


class StopControls:
    """The stop controls of every connected browser, enabled while a run is active."""

    def __init__(
        self, handles_lock: threading.RLock, on_stop: Callable[[], str] | None = None, token: str | None = None
    ) -> None:
        self._handles_lock = handles_lock  # the viewer's one lock for viser handles
        self._on_stop = on_stop
        self._token = token
        self._run_active = False
        self.by_client: dict[int, ClientControls] = {}

    def install(self, server: Any) -> None:
        server.on_client_connect(self._connected)
        server.on_client_disconnect(self._disconnected)

    def _connected(self, client: Any) -> None:
        gui = client.gui
        token_box = None
        if self._token is not None:
            token_box = gui.add_text(
                "Token", initial_value="", hint="the console's token (asked to stop a run)", order=1.0
            )
            uuid = getattr(getattr(token_box, "_impl", None), "uuid", None)
            if uuid:  # mask it: viser's text input has no password type
                # ...and tie the label to it: viser's <label for=uuid> names no element (its text
                # input gets no id), so a screen reader announces an unnamed field. HTML inserted by
                # viser runs no <script>; an image that fails to load runs its onerror, after the
                # field is on the page, and gives the input the id the label names.
                tie = (
                    "for(var l of document.querySelectorAll('label'))if(l.htmlFor==='" + uuid + "')"
                    "{var i=l.closest('div:has(> div > p > label)').querySelector('input');if(i)i.id=l.htmlFor}"
                )
                gui.add_html(
                    f'<style>div:has(> div > p > label[for="{uuid}"]) input '
                    "{ -webkit-text-security: disc; text-security: disc; }</style>"
                    f'<img src="data:," alt="" hidden onerror="{tie}">',
                    order=1.01,
                )
        with self._handles_lock:
            button = gui.add_button("Stop the run", color="red", disabled=not self._run_active, order=2.0)
            note = gui.add_markdown("", order=3.0)
            controls = ClientControls(token_box, button, note)
            self.by_client[client.client_id] = controls
        button.on_click(lambda _event: self._stop_clicked(controls))

    def _disconnected(self, client: Any) -> None:
        with self._handles_lock:
            self.by_client.pop(client.client_id, None)

    def _stop_clicked(self, controls: ClientControls) -> None:
        given = ""
        if controls.token_box is not None:
            given = controls.token_box.value.strip()
            controls.token_box.value = ""  # never left in the box
        if self._token is not None and not hmac.compare_digest(given.encode(), self._token.encode()):
            controls.note.content = "Wrong or missing token: the run goes on."
            return
        message = self._on_stop() if self._on_stop is not None else "no run manager"
        controls.note.content = message

    def set_enabled(self, enabled: bool) -> None:
        with self._handles_lock:
            self._run_active = enabled
            for controls in self.by_client.values():
                controls.stop_button.disabled = not enabled
                if enabled:
                    controls.note.content = ""
