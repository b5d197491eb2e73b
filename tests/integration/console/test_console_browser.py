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
    context = b.new_context(**{**p.devices["Pixel 5"], "viewport": PIXEL_5})
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
        _in_view(page, "start", sizes=(PIXEL_5,))
        page.screenshot(path=str(ARTIFACTS / "phone_start.png"))  # what the screen shows, as on the phone
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
        page.wait_for_function("document.getElementById('run-mode').textContent !== '-'", timeout=60_000)
        page.screenshot(path=str(ARTIFACTS / "phone_run.png"))
        page.click("#stop")
        # Stop means stopped: the start makes a real search, so the run cannot have ended by itself
        page.wait_for_function("document.getElementById('run-badge').textContent.includes('stopped')", timeout=300_000)
        row = live_console.console.store.get_run(run_id)
        assert row is not None and row["status"] == "stopped" and row["n_steps"] >= 2
        page.wait_for_function(
            "document.getElementById('run-outcome').textContent.includes('The operator stopped the run')",
            timeout=60_000,
        )
        # the end: the final step (not the one the live view last fetched) beside the outcome
        n = row["n_steps"]
        page.wait_for_function(
            "(n) => document.getElementById('run-mode').textContent.startsWith(`Step ${n}:`)", arg=n, timeout=60_000
        )
        assert page.inner_text("#run-step") == str(n)
        _in_view(page, "run-outcome", sizes=(PIXEL_5,))
        page.screenshot(path=str(ARTIFACTS / "phone_end.png"))
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
            "document.getElementById('details-summary').textContent.includes('The operator stopped the run')",
            timeout=60_000,
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
    step 7, every run, which stops by itself after 13 steps; the run is held before its fifth
    move, with its candidate, until the test moves the hold on (``provider.hold``; the real agent
    cannot promise a detection)."""
    from console.context import Console, ConsoleConfig
    from console.viewer import ViewerConfig
    from tests.helpers.console_testkit import Hold, ScriptedProvider

    provider = ScriptedProvider(stop_after=12, hold=Hold(at=4))
    console = Console(ConsoleConfig(data_dir=tmp_path / "data", viewer=ViewerConfig(port=0)), {"scripted": provider})
    server = LiveServer(console)
    yield server, provider
    server.close()


# the phone sizes of issue 33 (Chromium's viewports: the browser's own bars taken off)
PIXEL_5 = {"width": 393, "height": 727}
IPHONE_13 = {"width": 390, "height": 664}

_IN_VIEW_JS = """(id) => {
  const e = document.getElementById(id);
  if (!e) return `no #${id}`;
  const r = e.getBoundingClientRect();
  if (r.width === 0 || r.height === 0) return `#${id} is not shown`;
  if (r.top < 0 || r.bottom > innerHeight) return `#${id} at y ${Math.round(r.top)}-${Math.round(r.bottom)}, not within ${innerHeight}`;
  const hit = document.elementFromPoint(r.left + Math.min(r.width / 2, 20), r.top + r.height / 2);
  return hit && (e.contains(hit) || hit.contains(e)) ? "" : `#${id} is covered by ${hit && hit.outerHTML.slice(0, 60)}`;
}"""


def _in_view(page, *ids: str, sizes=(PIXEL_5, IPHONE_13)) -> None:
    """Each element is within the viewport and not covered, at each phone size (without scrolling)."""
    for size in sizes:
        page.set_viewport_size(size)
        page.wait_for_function("(w) => innerWidth === w", arg=size["width"])
        problems = [p for p in (page.evaluate(_IN_VIEW_JS, i) for i in ids) if p]
        assert not problems, (size, problems)
    page.set_viewport_size(sizes[0])


def _legend_rgb(page, legend_id: str) -> dict[str, tuple[int, int, int]]:
    colours = page.eval_on_selector_all(
        f"#{legend_id} span[data-key]",
        "els => els.map(e => [e.dataset.key, getComputedStyle(e.querySelector('i')).backgroundColor])",
    )
    return {k: tuple(int(v) for v in c[c.index("(") + 1 : c.index(")")].split(",")[:3]) for k, c in colours}


def _check_legends(page, legend_ids: list[str]) -> None:
    """Each colour of a legend means one thing, and the map's and the 3D view's colours are the
    ones the pictures and the scene draw (issue 33: a rejected candidate's purple was also the
    colour of the map's given-up cells)."""
    from console import pictures
    from console.viewer.scene import CANDIDATE_RGB

    for legend_id in legend_ids:
        rgb = _legend_rgb(page, legend_id)
        assert len(rgb) >= 10, (legend_id, rgb)
        for k1, c1 in rgb.items():
            for k2, c2 in rgb.items():
                if k1 < k2:
                    assert sum((a - b) ** 2 for a, b in zip(c1, c2)) ** 0.5 > 30, (legend_id, k1, k2, c1, c2)
        assert rgb["blacklist"] == pictures.BLACKLIST_RGB and rgb["collision"] == pictures.COLLISION_RGB, rgb
        if "rejected" in rgb:  # the 3D view's legend
            assert rgb["rejected"] == CANDIDATE_RGB["rejected"] and rgb["potential"] == CANDIDATE_RGB["potential"]
        else:
            assert rgb["candidate"] == pictures.CANDIDATE_MARK_RGB and rgb["explored"] == pictures.EXPLORED_RGB
    far = sum((a - b) ** 2 for a, b in zip(pictures.BLACKLIST_RGB, CANDIDATE_RGB["rejected"])) ** 0.5
    assert far > 60 and pictures.COLLISION_RGB != CANDIDATE_RGB["potential"]


def _a11y(page, what: str) -> None:
    from tests.helpers.a11y import check_page

    problems = check_page(page)
    assert not problems, (what, problems)


def test_scripted_run_on_phone_and_console(browser, scripted_console, tmp_path: Path) -> None:
    """One short scripted run followed on the phone (Pixel 5 and iPhone 13 sizes) and on the
    console (1280 x 800) with its 3D viewer: the layout, the legends, the words, the final state
    on every panel, the viewer left as it was by a page opening, the replay, accessibility."""
    from tests.helpers.console_testkit import encode, textured_rgb

    server, provider = scripted_console
    console = server.console
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    photo = tmp_path / "photo.jpg"
    photo.write_bytes(encode(textured_rgb(240, 320), "JPEG"))
    desk = b.new_context(viewport={"width": 1280, "height": 800})
    phone_ctx = b.new_context(**{**p.devices["Pixel 5"], "viewport": PIXEL_5})
    try:
        page = desk.new_page()
        page.goto(server.url + "/console")
        frame = page.wait_for_selector("#viewer-frame").content_frame()
        assert frame is not None
        # the page attaches its listeners only after /api/config answered (in the same task as
        # filling the backend filter, whose first option, 'any robot', is in the HTML)
        page.wait_for_function("document.querySelectorAll('#filter-backend option').length > 1")
        _check_legends(page, ["legend", "live-legend"])
        # the viewer's side panel is beside the scene, not over it (issue 33: it hid ~45% at 1280 x 800)
        canvas = frame.wait_for_selector("canvas", timeout=60_000)
        stop_button = frame.wait_for_selector("text=Stop the run", timeout=60_000)
        scene_box = poll(lambda: canvas.bounding_box(), lambda bb: bb is not None and bb["width"] > 200, 60, "canvas")
        panel_x = stop_button.bounding_box()["x"]
        assert scene_box["x"] + scene_box["width"] <= panel_x, (scene_box, panel_x)
        _a11y(page, "console")
        calib = desk.new_page()
        calib.goto(server.url + "/calibrate")
        calib.wait_for_load_state("networkidle")
        _a11y(calib, "calibrate")
        calib.close()

        phone = phone_ctx.new_page()
        phone.goto(server.url + "/phone")
        phone.wait_for_function("document.querySelector('#backend option') !== null")
        _a11y(phone, "phone")
        phone.set_input_files("#file-input", str(photo))
        phone.wait_for_function("document.getElementById('preview').naturalWidth > 0")
        phone.wait_for_selector("#start:not([disabled])")
        _in_view(phone, "start")  # issue 33: below the fold (y 1164 in 727) after choosing a photo
        phone.screenshot(path=str(ARTIFACTS / "phone_start_scripted.png"))
        phone.click("#start")
        poll(lambda: console.manager.active_run_id, lambda r: r is not None, 30, "active run")
        run_id = console.manager.active_run_id
        # the run is held mid-way, with its candidate (from step 4), until released below
        poll(lambda: console.store.get_run(run_id)["n_steps"], lambda n: n == 4, 60, "a candidate")
        # the console page (which did not start the run) shows its live state from the run's next
        # step on: one more move once the page follows the run
        page.wait_for_function("(id) => document.getElementById('live-id').textContent === id", arg=run_id)
        provider.hold.move_to(5)
        poll(lambda: console.store.get_run(run_id)["n_steps"], lambda n: n == 5, 60, "the next step")
        phone.wait_for_function("document.getElementById('run-mode').textContent !== '-'", timeout=60_000)
        phone.wait_for_selector("#live-map:not([hidden])", timeout=60_000)
        _in_view(phone, "run-mode", "run-score", "run-candidates", "stop")
        _check_legends(phone, ["live-legend"])
        phone.screenshot(path=str(ARTIFACTS / "phone_mid_run_scripted.png"))
        # the console's candidate panel during the run: the candidate, its state, views, score, distance
        page.wait_for_selector("#candidates table.cands tr.cand", timeout=60_000)
        row = page.inner_text("#candidates table.cands tr.cand")
        assert "#1" in row and "0.4 m" in row and "12.5" in row
        frame.wait_for_selector("text=/Step \\d+:/", timeout=60_000)
        # the selected run's details count its steps while it runs (they said "0 steps so far")
        page.wait_for_function(
            "() => /[1-9]\\d* steps so far/.test(document.getElementById('details-summary').textContent)",
            timeout=60_000,
        )
        page.locator("#candidates").scroll_into_view_if_needed()
        page.screenshot(path=str(ARTIFACTS / "console_candidates.png"))
        provider.hold.release()
        poll(lambda: console.store.get_run(run_id)["status"], lambda s: s == "finished", 120, "end")
        n = console.store.get_run(run_id)["n_steps"]
        assert n == 13

        # the end on every panel: the final step and the outcome (issue 33: stale by a step or more)
        phone.wait_for_selector("#run-outcome:not([hidden]) .summary", timeout=60_000)
        phone.wait_for_function(
            "(n) => document.getElementById('run-mode').textContent.startsWith(`Step ${n}:`)", arg=n
        )
        assert phone.inner_text("#run-step") == str(n)
        assert phone.locator("#run-phase").is_hidden()  # the outcome says how it ended
        assert "given up: #1 (unreachable for 10 steps)" in phone.inner_text("#run-candidates")
        assert (
            phone.inner_text("#run-score-label") == "Best match"
            and phone.inner_text("#run-target-label") == "to object"
        )
        outcome = phone.inner_text("#run-outcome .summary")
        headline = phone.inner_text("#run-outcome .headline").rstrip(".")
        assert outcome.count(headline) == 1, outcome  # issue 33: "Found it Found it: ..."
        assert phone.locator("#run-outcome details.tech").count() == 1  # the technical account, closed
        assert not phone.eval_on_selector("#run-outcome details.tech", "d => d.open")
        _in_view(phone, "run-outcome")  # issue 33: the result sentence was below the fold
        phone.screenshot(path=str(ARTIFACTS / "phone_end_scripted.png"))
        page.wait_for_function(
            "(n) => document.getElementById('live-words').textContent.startsWith(`Step ${n}:`)", arg=n, timeout=60_000
        )
        page.wait_for_selector("#live-outcome:not([hidden]) .summary", timeout=60_000)
        assert "ended" in page.inner_text("#live-state")
        # the 3D view stays on the run's last step, with the outcome (issue 33: it jumped to a replay's step 1)
        frame.wait_for_selector(f"text=/Last step: Step {n}:/", timeout=60_000)
        page.wait_for_selector(f"#details-id:text('{run_id}')", timeout=60_000)
        page.wait_for_function("() => document.getElementById('replay').dataset.step !== undefined", timeout=60_000)
        assert page.get_attribute("#replay", "data-step") == str(n - 1)  # the replay opens on the end
        assert console.viewer.replay_step is None and console.viewer.last_published_step == n - 1
        # opening the console elsewhere changes nothing others are watching (issue 33: step 1 of the latest run)
        other = desk.new_page()
        other.goto(server.url + "/console")
        other.wait_for_function("() => document.getElementById('replay').dataset.step !== undefined", timeout=60_000)
        other.close()
        assert console.viewer.replay_step is None
        # the operator's words: no developer words in a step, the technical line behind a disclosure
        words = page.inner_text("#replay-words")
        assert words.startswith(f"Step {n}:") and "scripted" not in words
        assert "agent: scripted step 12" in page.eval_on_selector("#replay-detail", "e => e.textContent")
        _a11y(page, "console after the run")
        _a11y(phone, "phone after the run")

        # the replay: jump to the first detection, scrub, and the same step in the 3D viewer
        page.click("#jump-first-detection")
        page.wait_for_function("() => document.getElementById('replay').dataset.step === '3'", timeout=60_000)
        assert page.locator("#replay-candidates tr.cand.confirmed").count() == 1
        page.click("#jump-rejected-0")
        page.wait_for_function("() => document.getElementById('replay').dataset.step === '6'", timeout=60_000)
        assert page.locator("#replay-candidates tr.cand.rejected").count() == 1
        assert "unreachable for 10 steps" in page.inner_text("#replay-candidates tr.cand.rejected")
        _scrub(page, 10)
        assert page.get_attribute("#replay-frame", "src").endswith("/replay/10/frame.jpg")
        frame.wait_for_selector("text=/Replay of run/", timeout=60_000)
        poll(lambda: console.viewer.replay_step, lambda s: s == 10, 60, "viewer at the replayed step")
        page.locator("#replay").scroll_into_view_if_needed()
        page.screenshot(path=str(ARTIFACTS / "console_replay.png"))
    finally:
        provider.hold.release()
        phone_ctx.close()
        desk.close()


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


def test_a_slow_answer_for_an_earlier_click_does_not_overwrite_the_run_shown(browser, tmp_path: Path) -> None:
    """Two finished runs; the answer for the first run's details is held back 1.5 s in the page
    (its fetch), and the second run is clicked meanwhile: the details show the second run when
    the first's answer lands, and stay so (an answer that is not the latest is dropped)."""
    import httpx

    from console.context import Console, ConsoleConfig
    from tests.helpers.console_testkit import ScriptedProvider, encode, textured_rgb

    server = LiveServer(
        Console(ConsoleConfig(data_dir=tmp_path / "data", viewer=None), {"scripted": ScriptedProvider(stop_after=2)})
    )
    try:
        photo = encode(textured_rgb(96, 128), "PNG")
        ids = []
        for _ in range(2):
            resp = httpx.post(
                f"{server.url}/api/runs",
                files={"goal_image": ("g.png", photo, "image/png")},
                data={"backend": "scripted"},
            )
            assert resp.status_code == 201, resp.text
            ids.append(resp.json()["id"])
            poll(lambda: httpx.get(f"{server.url}/api/runs/{ids[-1]}").json()["status"], lambda s: s == "finished", 60)
        first, second = ids
        _, b = browser
        page = b.new_context(viewport={"width": 1280, "height": 800}).new_page()
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("requestfailed", lambda req: errors.append(req.url))
        page.add_init_script(
            """(() => {
              const fetch0 = window.fetch;
              window.fetch = async (url, opts) => {
                const r = await fetch0(url, opts);
                if (window.__slow && String(url).endsWith(`/api/runs/${window.__slow}`)) {
                  await new Promise((ok) => setTimeout(ok, 1500));
                  window.__landed = true;
                }
                return r;
              };
            })()"""
        )
        page.goto(server.url + "/console")
        poll(lambda: page.text_content("#details-id") or "", lambda t: t in ids, 30, "a run's details")
        page.evaluate("(id) => { window.__slow = id; }", first)
        page.click(f"#runs tr[data-run='{first}']")
        page.click(f"#runs tr[data-run='{second}']")
        poll(lambda: page.text_content("#details-id") or "", lambda t: t == second, 10, "the second run's details")
        page.wait_for_function("window.__landed === true", timeout=10_000)  # the first run's answer
        page.wait_for_timeout(300)  # ... and what the page does with it
        assert page.text_content("#details-id") == second
        assert page.eval_on_selector("#runs tr.selected", "e => e.dataset.run") == second
        assert not errors, errors
    finally:
        server.close()
