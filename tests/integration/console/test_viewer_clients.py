"""The viser viewer's stop control is per client: two browsers on one viewer (real
Chromium, viser's real websocket). A token typed in one never reaches the other, is
masked, and is cleared after use."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from console.viewer import Viewer, ViewerConfig
from tests.helpers.console_live import ARTIFACTS, poll

pytestmark = pytest.mark.browser

TOKEN = "s3cret-token-for-the-test"
TOKEN_INPUT = 'div:has(> div > p > label:text-is("Token")) input'


@pytest.fixture
def viewer() -> Iterator[tuple[Viewer, list[str]]]:
    stops: list[str] = []
    v = Viewer(ViewerConfig(port=0), on_stop=lambda: stops.append("stop") or "Stopping run abc...", token=TOKEN)
    v.run_started("abcdefabcdef", np.full((32, 32, 3), 90, np.uint8), {"backend": "test"})  # enables Stop
    try:
        yield v, stops
    finally:
        v.close()


def _open(browser, url: str, contexts: list):
    """A new browser (context) on the viewer; the page loads while the caller goes on."""
    p, b = browser
    context = b.new_context(viewport={"width": 1280, "height": 800})
    contexts.append(context)
    page = context.new_page()
    page.goto(url)
    return page


def _ready(page) -> None:
    page.wait_for_selector(TOKEN_INPUT, timeout=60_000)
    page.wait_for_selector("button:has-text('Stop the run'):not([disabled])", timeout=60_000)


def test_token_box_is_per_client_masked_and_cleared(browser, viewer) -> None:
    v, stops = viewer
    url = f"http://127.0.0.1:{v.port}/"
    contexts: list = []
    try:
        # both viewers load side by side (each builds its scene, in software)
        a = _open(browser, url, contexts)
        b = _open(browser, url, contexts)
        _ready(a)
        _ready(b)
        poll(lambda: len(v.controls.by_client), lambda n: n == 2, 30, "two clients with their own controls")
        a.fill(TOKEN_INPUT, TOKEN)
        # the server has A's token in A's box only...
        poll(
            lambda: [c.token_box.value for c in v.controls.by_client.values()],
            lambda vals: sorted(vals) == ["", TOKEN],
            30,
            "A's box",
        )
        assert b.input_value(TOKEN_INPUT) == ""
        # the "Token" label names the box (a screen reader announces it; clicking it focuses it)
        named = a.get_by_label("Token", exact=True)
        assert named.count() == 1 and named.input_value() == TOKEN
        # A's box is masked on screen
        assert a.eval_on_selector(TOKEN_INPUT, "el => getComputedStyle(el).webkitTextSecurity") == "disc"
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        a.screenshot(path=str(ARTIFACTS / "viewer_token_masked.png"))

        # B (no token) presses Stop: refused, nothing stopped
        b.click("button:has-text('Stop the run')")
        b.wait_for_selector("text=Wrong or missing token", timeout=30_000)
        assert stops == []
        # B with a wrong token: both boxes hold their own text, on the server and on each page
        b.fill(TOKEN_INPUT, "guess")
        poll(
            lambda: sorted(c.token_box.value for c in v.controls.by_client.values()),
            lambda vals: vals == ["guess", TOKEN],
            30,
            "B's guess",
        )
        assert b.input_value(TOKEN_INPUT) == "guess" and a.input_value(TOKEN_INPUT) == TOKEN
        # ...and B's Stop is refused, and its box is cleared
        b.click("button:has-text('Stop the run')")
        poll(lambda: b.input_value(TOKEN_INPUT), lambda val: val == "", 30, "B's box cleared")
        assert stops == []
        # A (right token) presses Stop: the run is stopped and A's box is cleared
        a.click("button:has-text('Stop the run')")
        poll(lambda: stops, lambda s: s == ["stop"], 30, "stop from A")
        a.wait_for_selector("text=Stopping run abc", timeout=30_000)
        poll(lambda: a.input_value(TOKEN_INPUT), lambda val: val == "", 30, "A's box cleared")
        assert all(c.token_box.value == "" for c in v.controls.by_client.values())
        # only A was told; B's note still says its own attempt failed
        assert b.locator("text=Stopping run abc").count() == 0
    finally:
        for context in contexts:
            context.close()
