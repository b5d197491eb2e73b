"""The pages in a real headless Chromium (Debian's package) driven by Playwright.

Screenshots go to test-artifacts/console/ (gitignored)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from console_live import ARTIFACTS, LiveServer, poll

pytestmark = pytest.mark.browser

def _gallery_file(server: LiveServer, tmp_path: Path) -> tuple[Path, dict, dict]:
    """A gallery goal image saved as a file (as a phone would have it) and the start near it."""
    import httpx

    home = httpx.get(f"{server.url}/api/backends/sim").json()["homes"][0]
    for g in home["gallery"]:
        start = next((s for s in home["starts"] if s["id"] == f"n{g['instance']}"), None)
        if start is not None:
            break
    path = tmp_path / "goal-photo.png"
    path.write_bytes(httpx.get(server.url + g["url"]).content)
    return path, g, start


def test_phone_choose_photo_start_and_follow(browser, live_console: LiveServer, tmp_path: Path) -> None:
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo, g, start = _gallery_file(live_console, tmp_path)
    context = b.new_context(**p.devices["Pixel 7"])
    page = context.new_page()
    try:
        page.goto(live_console.url + "/")
        page.wait_for_url("**/phone")  # the landing page sends small screens to the phone page
        assert page.locator("#camera-input").get_attribute("capture") == "environment"
        page.wait_for_selector("#sim-home")  # simulator homes listed
        page.select_option("#sim-start", start["id"])
        page.set_input_files("#file-input", str(photo))
        page.wait_for_selector("#preview:not([hidden])")
        page.wait_for_function("document.getElementById('preview').naturalWidth > 0")
        page.click("#start")
        page.wait_for_function("document.getElementById('run-id').textContent.length === 12")
        run_id = page.inner_text("#run-id")
        # progress arrives over the status stream: the step counter moves
        poll(lambda: page.inner_text("#run-step"), lambda t: t not in ("-", "") and int(t.split()[0]) >= 2, 300, "progress")
        page.screenshot(path=str(ARTIFACTS / "phone_run.png"), full_page=True)
        page.click("#stop")
        page.wait_for_function(
            "['stopped','finished'].some(s => document.getElementById('run-badge').textContent.includes(s))", timeout=300_000
        )
        page.screenshot(path=str(ARTIFACTS / "phone_stopped.png"), full_page=True)
        row = live_console.console.store.get_run(run_id)
        assert row is not None and row["status"] in ("stopped", "finished") and row["n_steps"] >= 2
    finally:
        context.close()


def test_console_viewer_renders_and_updates_during_a_run(browser, live_console: LiveServer, tmp_path: Path) -> None:
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo, g, start = _gallery_file(live_console, tmp_path)
    context = b.new_context(viewport={"width": 1440, "height": 900})
    page = context.new_page()
    try:
        page.goto(live_console.url + "/console")
        frame_el = page.wait_for_selector("#viewer-frame")
        frame = frame_el.content_frame()
        assert frame is not None
        canvas = frame.wait_for_selector("canvas", timeout=60_000)
        poll(lambda: canvas.bounding_box(), lambda bb: bb is not None and bb["width"] > 200 and bb["height"] > 200, 60, "canvas size")
        page.wait_for_selector("#sim-home")
        page.select_option("#sim-start", start["id"])
        page.set_input_files("#file-input", str(photo))
        page.click("#start")
        poll(lambda: live_console.console.manager.active_run_id, lambda r: r is not None, 30, "active run")
        run_id = live_console.console.manager.active_run_id
        # the viewer's own status text follows the steps...
        frame.wait_for_selector("text=/step \\d+/", timeout=300_000)
        first = hashlib.sha256(canvas.screenshot()).hexdigest()
        # ...and the 3D canvas changes as the robot moves and the map grows
        poll(lambda: hashlib.sha256(canvas.screenshot()).hexdigest(), lambda h: h != first, 300, "canvas update")
        poll(lambda: live_console.console.store.get_run(run_id)["n_steps"], lambda n: n >= 4, 300, "four steps")
        page.screenshot(path=str(ARTIFACTS / "console_live_run.png"))
        page.click("#stop")
        poll(lambda: live_console.console.store.get_run(run_id)["status"], lambda s: s in ("stopped", "finished"), 300, "stop")
        page.wait_for_selector("#artifacts img", timeout=60_000)
        page.screenshot(path=str(ARTIFACTS / "console_after_run.png"))
    finally:
        context.close()


def test_viewer_on_a_phone_screen(browser, live_console: LiveServer, tmp_path: Path) -> None:
    """The 3D viewer itself on a phone-sized screen: canvas and the stop button are there."""
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    context = b.new_context(**p.devices["Pixel 7"])
    page = context.new_page()
    try:
        viewer_port = live_console.console.viewer.port
        page.goto(f"http://127.0.0.1:{viewer_port}/")
        canvas = page.wait_for_selector("canvas", timeout=60_000)
        box = poll(lambda: canvas.bounding_box(), lambda bb: bb is not None and bb["width"] > 100, 60, "canvas")
        assert box["width"] <= 500  # laid out for the phone's width
        page.wait_for_selector("text=Stop the run", timeout=60_000)
        page.screenshot(path=str(ARTIFACTS / "viewer_phone.png"))
    finally:
        context.close()
