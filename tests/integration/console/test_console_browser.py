"""The pages in a real headless Chromium (Debian's package) driven by Playwright, with the
real simulator and agent behind them.

Screenshots go to $IMGNAV_TEST_ARTIFACTS/console/ (default: the temp dir, never the checkout); the ones in docs/console/ are
taken from these."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from tests.helpers.console_live import ARTIFACTS, LiveServer, poll

pytestmark = pytest.mark.browser


def _gallery_file(server: LiveServer, tmp_path: Path, near: bool) -> tuple[Path, dict, dict]:
    """A gallery goal image saved as a file (as a phone would have it) and a start: the one
    near it (a short run) or the page's default for it (a real search)."""
    import httpx

    home = httpx.get(f"{server.url}/api/backends/sim").json()["homes"][0]
    order = ["couch", "bed", "tv", "chair", "potted plant", "toilet"]
    for g in sorted(home["gallery"], key=lambda g: order.index(g["category"])):
        start_id = f"n{g['instance']}" if near else g.get("default_start")
        start = next((s for s in home["starts"] if s["id"] == start_id), None)
        if start is not None:
            break
    path = tmp_path / "goal-photo.png"
    path.write_bytes(httpx.get(server.url + g["url"]).content)
    return path, g, start


def _scrub(page, step: int) -> None:
    """Move the replay slider as a finger would (value + input event), then wait for that step."""
    page.eval_on_selector(
        "#replay-slider", "(el, v) => { el.value = String(v); el.dispatchEvent(new Event('input')); }", step + 1
    )
    page.wait_for_function(
        "(s) => document.getElementById('replay').dataset.step === String(s)"
        " && document.getElementById('replay-words').textContent.startsWith(`Step ${s + 1}:`)",
        arg=step,
        timeout=60_000,
    )
    page.wait_for_function(
        "() => ['replay-frame', 'replay-map'].every(id => { const i = document.getElementById(id);"
        " return i.complete && i.naturalWidth > 0; })",
        timeout=60_000,
    )


def test_phone_start_follow_stop_and_replay(browser, live_console: LiveServer, tmp_path: Path) -> None:
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo, g, start = _gallery_file(live_console, tmp_path, near=False)
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
        # the progress card comes into view by itself (it was below the fold)
        page.wait_for_function(
            "() => { const r = document.getElementById('progress-card').getBoundingClientRect();"
            " return r.top < window.innerHeight && r.bottom > 0; }",
            timeout=30_000,
        )
        # progress arrives over the status stream: the step counter moves, words for people
        poll(lambda: page.inner_text("#run-step"), lambda t: t not in ("-", "") and int(t) >= 2, 300, "progress")
        phase = page.inner_text("#run-phase")
        assert "look_around" not in phase and "TURN_LEFT" not in phase, phase
        page.wait_for_selector("#live-frame:not([hidden])", timeout=60_000)
        page.screenshot(path=str(ARTIFACTS / "phone_run.png"), full_page=True)
        page.click("#stop")
        # Stop means stopped: the start makes a real search, so the run cannot have ended by itself
        page.wait_for_function("document.getElementById('run-badge').textContent.includes('stopped')", timeout=300_000)
        row = live_console.console.store.get_run(run_id)
        assert row is not None and row["status"] == "stopped" and row["n_steps"] >= 2
        page.wait_for_function(
            "document.getElementById('run-outcome').textContent.includes('Stopped by the operator')", timeout=60_000
        )
        # the replay of the run on the phone: scrub to a step, see its picture and map
        page.wait_for_selector("#replay-slider", timeout=60_000)
        last = row["n_steps"] - 1
        _scrub(page, last)
        _scrub(page, 1)
        assert page.get_attribute("#replay-frame", "src").endswith("/replay/1/frame.jpg")
        page.locator("#replay-card").scroll_into_view_if_needed()
        page.screenshot(path=str(ARTIFACTS / "phone_replay.png"), full_page=True)
    finally:
        context.close()


def test_console_live_run_in_the_viewer_and_stop(browser, live_console: LiveServer, tmp_path: Path) -> None:
    """The real simulator behind the desktop page: the viewer follows the run, Stop stops it."""
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo, g, start = _gallery_file(live_console, tmp_path, near=False)
    context = b.new_context(viewport={"width": 1440, "height": 900})
    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    try:
        page.goto(live_console.url + "/console")
        frame = page.wait_for_selector("#viewer-frame").content_frame()
        assert frame is not None
        canvas = frame.wait_for_selector("canvas", timeout=60_000)
        poll(
            lambda: canvas.bounding_box(),
            lambda bb: bb is not None and bb["width"] > 200 and bb["height"] > 200,
            60,
            "canvas size",
        )
        page.wait_for_selector("#sim-home")
        page.click(f"#gallery figure[data-item='{g['item']}']")
        # picking the gallery object chose a start that makes a real search
        poll(lambda: page.input_value("#sim-start"), lambda v: v == g["default_start"], 30, "default start")
        page.wait_for_function("document.getElementById('preview').naturalWidth > 0")
        first = hashlib.sha256(canvas.screenshot()).hexdigest()  # the viewer before the run
        page.click("#start")
        poll(lambda: live_console.console.manager.active_run_id, lambda r: r is not None, 30, "active run")
        run_id = live_console.console.manager.active_run_id
        poll(lambda: live_console.console.store.get_run(run_id)["n_steps"], lambda n: n >= 1, 300, "first step")
        # the viewer's own status text follows the steps, numbered as on the pages
        frame.wait_for_selector("text=/Step \\d+:/", timeout=300_000)
        # Stop at once: the agent finds some goals of a real search within a minute, and a run
        # that has ended cannot show that Stop works (the pictures below stay from the run)
        page.click("#stop")
        poll(
            lambda: live_console.console.store.get_run(run_id)["status"],
            lambda s: s in ("stopped", "finished", "failed"),
            300,
            "end",
        )
        assert (
            live_console.console.store.get_run(run_id)["status"] == "stopped"
        )  # a real search: only Stop ends it this early
        # the viewer followed the run (the 3D canvas shows its map and pose), the page its live picture
        poll(lambda: hashlib.sha256(canvas.screenshot()).hexdigest(), lambda h: h != first, 300, "canvas update")
        page.wait_for_selector("#live-frame[src*='/replay/']", timeout=60_000)
        page.screenshot(path=str(ARTIFACTS / "console_live_run_sim.png"))
        page.wait_for_function(
            "document.getElementById('details-summary').textContent.includes('Stopped by the operator')", timeout=60_000
        )
        # the run table fits its card (SPL visible) at desktop widths
        for width in (1280, 2560):
            page.set_viewport_size({"width": width, "height": 900})
            fits = page.eval_on_selector(".table-wrap", "el => el.scrollWidth <= el.clientWidth + 1")
            assert fits, f"run table wider than its card at {width} px"
        assert not [e for e in errors if "favicon" in e], errors
    finally:
        context.close()


@pytest.fixture
def scripted_console(tmp_path: Path):
    """A console whose robot is scripted: a goal candidate appears at step 4 and is rejected at
    step 7, every run; each move takes 0.5 s (the real agent cannot promise a detection)."""
    from console.context import Console, ConsoleConfig
    from console.viewer import ViewerConfig
    from tests.helpers.console_testkit import ScriptedProvider

    console = Console(
        ConsoleConfig(data_dir=tmp_path / "data", viewer=ViewerConfig(port=0)),
        {"scripted": ScriptedProvider(stop_after=30, step_s=0.5)},
    )
    server = LiveServer(console)
    yield server
    server.close()


def test_console_candidates_live_then_replay_in_page_and_viewer(
    browser, scripted_console: LiveServer, tmp_path: Path
) -> None:
    from tests.helpers.console_testkit import encode, textured_rgb

    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo = tmp_path / "photo.jpg"
    photo.write_bytes(encode(textured_rgb(240, 320), "JPEG"))
    context = b.new_context(viewport={"width": 1440, "height": 900})
    page = context.new_page()
    try:
        page.goto(scripted_console.url + "/console")
        frame = page.wait_for_selector("#viewer-frame").content_frame()
        # the page attaches its file listener only after /api/config answered (in the same task as
        # filling the backend filter): a file set before that is lost (seen under load in CI)
        page.wait_for_function("document.querySelector('#filter-backend option') !== null")
        page.set_input_files("#file-input", str(photo))
        page.wait_for_selector("#start:not([disabled])")
        page.click("#start")
        poll(lambda: scripted_console.console.manager.active_run_id, lambda r: r is not None, 30, "active run")
        run_id = scripted_console.console.manager.active_run_id
        # the candidate panel during the run: the candidate with its state, views, score, distance
        page.wait_for_selector("#candidates table.cands tr.cand", timeout=60_000)
        row = page.inner_text("#candidates table.cands tr.cand")
        assert "#1" in row and "0.4 m" in row and "12.5" in row
        page.screenshot(path=str(ARTIFACTS / "console_candidates.png"))
        poll(lambda: scripted_console.console.store.get_run(run_id)["status"], lambda s: s == "finished", 120, "end")
        # the replay: jump to the first detection, scrub, and the same step in the 3D viewer
        page.wait_for_selector(f"#details-id:text('{run_id}')", timeout=60_000)
        page.wait_for_selector("#jump-first-detection:not([disabled])", timeout=60_000)
        page.click("#jump-first-detection")
        page.wait_for_function("() => document.getElementById('replay').dataset.step === '3'", timeout=60_000)
        assert page.locator("#replay-candidates tr.cand.confirmed").count() == 1
        page.click("#jump-rejected-0")
        page.wait_for_function("() => document.getElementById('replay').dataset.step === '6'", timeout=60_000)
        assert page.locator("#replay-candidates tr.cand.rejected").count() == 1
        assert "unreachable for 10 steps" in page.inner_text("#replay-candidates tr.cand.rejected")
        _scrub(page, 20)
        assert page.get_attribute("#replay-frame", "src").endswith("/replay/20/frame.jpg")
        frame.wait_for_selector("text=/Replay of run/", timeout=60_000)
        poll(lambda: scripted_console.console.viewer.replay_step, lambda s: s == 20, 60, "viewer at the replayed step")
        page.locator("#replay").scroll_into_view_if_needed()
        page.screenshot(path=str(ARTIFACTS / "console_replay.png"))
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
