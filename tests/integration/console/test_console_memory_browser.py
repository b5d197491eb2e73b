"""The console page's memory panel (issue 31) in a real headless Chromium, with the real
simulator and agent: empty before the first run in a home, its map and known objects (with the
goal photo each was asked with) after one, "Find it again" starts a run from memory with that
photo, and Forget empties it; with the fake Stretch, the robot's home and why its memory was
dropped."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from console.store import FINAL_STATUSES as FINAL
from tests.helpers.console_live import ARTIFACTS, LiveServer, poll, sim_console

pytestmark = pytest.mark.browser

# the memory panel's layout: its box, how far its content overflows it, the elements in it wider
# than it, its buttons (Find it again, Forget) and the photos of the known objects (CSS px)
_PHONE_FACTS_JS = """() => {
  const box = (e) => { const r = e.getBoundingClientRect();
    return { left: r.left, right: r.right, top: r.top, bottom: r.bottom, width: r.width, height: r.height }; };
  const card = document.getElementById("memory-card");
  const edge = card.getBoundingClientRect().right;
  return {
    page_width: document.documentElement.scrollWidth,
    card: box(card),
    card_overflow: card.scrollWidth - card.clientWidth,
    wider_than_card: [...card.querySelectorAll("*")].filter((e) => e.getBoundingClientRect().right > edge + 0.5)
      .map((e) => e.outerHTML.slice(0, 80)),
    buttons: [...card.querySelectorAll("button")].map(box),
    thumbs: [...card.querySelectorAll("#memory-objects .memory-thumb")].map(box),
  };
}"""


@pytest.fixture
def server(sim_data_dir: Path, tmp_path: Path) -> Iterator[LiveServer]:
    data = tmp_path / "data"
    shutil.copytree(sim_data_dir / "sim", data / "sim")
    live = LiveServer(sim_console(data, viewer=False))
    yield live
    live.close()


def test_the_memory_panel_shows_the_homes_map_and_objects_and_forgets_it(browser, server: LiveServer) -> None:
    import httpx

    from tests.helpers.a11y import check_page

    _, b = browser
    page = b.new_context(viewport={"width": 1440, "height": 900}).new_page()
    errors: list[str] = []
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    failed: list[str] = []  # the console message of a failed load does not name the URL
    page.on("response", lambda r: failed.append(f"{r.status} {r.url}") if r.status >= 400 else None)
    page.goto(server.url + "/console")
    page.wait_for_selector("#sim-home")
    home = page.input_value("#sim-home")
    poll(lambda: page.is_visible("#memory-card"), bool, 30, "memory card")
    assert page.text_content("#memory-home") == home
    poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("Nothing yet"), 30, "empty memory")
    assert page.is_disabled("#memory-forget") and not page.is_visible("#memory-map")

    # a run in this home (started through the API; the page follows the console's events)
    desc = httpx.get(f"{server.url}/api/backends/sim").json()["homes"][0]
    g = desc["gallery"][0]
    png = httpx.get(server.url + g["url"]).content
    resp = httpx.post(
        f"{server.url}/api/runs",
        files={"goal_image": ("g.png", png, "image/png")},
        data={"home": home, "gallery_item": g["item"], "max_steps": "6"},  # finds the couch from the first start
    )
    assert resp.status_code == 201, resp.text
    run_id = resp.json()["id"]
    poll(lambda: httpx.get(f"{server.url}/api/runs/{run_id}").json()["status"], lambda s: s in FINAL, 600, "run end")
    memory = httpx.get(f"{server.url}/api/memory/{home}").json()
    assert len(memory["goals"]) == 1 and not memory["in_use"]

    poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("1 request"), 30, "memory words")
    assert f"{memory['keyframes']} remembered view" in (page.text_content("#memory-words") or "")
    poll(
        lambda: page.evaluate("() => document.getElementById('memory-map').naturalWidth"),
        lambda w: w == 480,
        30,
        "memory map loaded",
    )
    (known,) = memory["objects"]
    assert known["run_id"] == run_id and known["goal_url"]
    items = page.locator("#memory-objects li").all_text_contents()
    assert len(items) == 1 and items[0].startswith("request 1: ") and items[0].endswith("Find it again"), items
    thumb = "#memory-objects li[data-request='1'] img.memory-thumb"
    assert page.get_attribute(thumb, "src") == known["goal_url"]
    poll(lambda: page.evaluate(f'() => document.querySelector("{thumb}").naturalWidth'), bool, 30, "thumbnail")
    assert not page.is_disabled("#memory-forget")
    problems = check_page(page, every_badge=True)  # every badge state too, not only the idle one shown now
    assert not problems, problems
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.locator("#memory-card").screenshot(path=str(ARTIFACTS / "memory_panel.png"))

    # at a phone's width (the same page, its viewport resized): the panel fits the screen, its
    # photos are in view at a size one can see, its buttons are a finger's target (44 CSS px)
    page.set_viewport_size({"width": 390, "height": 844})
    page.locator("#memory-objects").scroll_into_view_if_needed()
    phone = page.evaluate(_PHONE_FACTS_JS)
    assert phone["page_width"] <= 390 and phone["card"]["right"] <= 390, phone  # no sideways scrolling
    assert phone["card_overflow"] <= 0 and not phone["wider_than_card"], phone
    assert phone["buttons"] and all(b["height"] >= 44 and b["width"] >= 44 for b in phone["buttons"]), phone
    assert len(phone["thumbs"]) == len(memory["objects"]), phone
    for t in phone["thumbs"]:
        assert 0 <= t["left"] and t["right"] <= 390 and 0 <= t["top"] and t["bottom"] <= 844, phone
        assert 44 <= t["width"] <= 120 and t["height"] == t["width"], phone
    page.locator("#memory-card").screenshot(path=str(ARTIFACTS / "memory_panel_phone.png"))
    page.set_viewport_size({"width": 1440, "height": 900})

    # "Find it again": a run in this home, from memory, with the request's goal photo (stopped at once)
    page.click("#memory-objects li[data-request='1'] button.memory-again")
    poll(lambda: page.is_enabled("#stop"), bool, 60, "run from memory active")
    assert page.is_disabled("#memory-objects li[data-request='1'] button.memory-again")  # one run at a time
    again = httpx.get(f"{server.url}/api/runs").json()["runs"][0]
    assert again["id"] != run_id and again["goal"]["from_run"] == run_id, again
    assert again["options"]["home"] == home and "memory" not in again["options"]  # memory on
    page.click("#stop")
    poll(lambda: httpx.get(f"{server.url}/api/runs/{again['id']}").json()["status"], lambda s: s in FINAL, 300, "end")
    photos = [httpx.get(f"{server.url}/api/runs/{r}/artifacts/goal.png").content for r in (run_id, again["id"])]
    assert photos[0] == photos[1]
    assert httpx.get(f"{server.url}/api/memory/{home}").json()["goals"][-1]["run_id"] == again["id"]
    poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("2 requests"), 30, "second request")

    page.click("#memory-forget")
    poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("Nothing yet"), 30, "forgotten")
    assert httpx.get(f"{server.url}/api/memory/{home}").json()["goals"] == []
    assert page.is_disabled("#memory-forget") and not page.is_visible("#memory-map")

    # unticked: the next run starts from nothing and leaves the memory as it is (stopped at once here)
    page.uncheck("#memory-use")
    page.click(f"#gallery figure[data-item='{g['item']}']")
    poll(lambda: page.is_enabled("#start"), bool, 30, "start enabled")
    page.click("#start")
    poll(lambda: page.is_enabled("#stop"), bool, 60, "run active")
    page.click("#stop")
    runs = poll(
        lambda: httpx.get(f"{server.url}/api/runs").json()["runs"],
        lambda rs: rs and rs[0]["id"] not in (run_id, again["id"]) and rs[0]["status"] in FINAL,
        300,
        "third run end",
    )
    assert runs[0]["options"]["memory"] == "off", runs[0]["options"]
    assert httpx.get(f"{server.url}/api/memory/{home}").json()["goals"] == []
    assert (page.text_content("#memory-words") or "").startswith("Nothing yet")
    assert not errors, (errors, failed)


def test_the_memory_panel_shows_the_robots_home_and_why_it_was_dropped(browser, tmp_path: Path) -> None:
    """The Stretch chosen: the robot's home (console/robot_memory.py), its known object after a run,
    "Find it again" from memory, and, after the base was pushed by hand, the drop and its reason in
    the panel and the page's log."""
    import httpx

    from agent.types import Pose2D
    from robot.fake_server import FakeStretch
    from robot.fake_world import BoxWorld
    from tests.helpers.a11y import check_page
    from tests.helpers.console_testkit import encode
    from tests.helpers.robot_console import stretch_console

    world = BoxWorld(pillars=((1.5, 0.5, 0.25),), start_world=Pose2D(-0.5, 0.5, 0.0))  # a pillar ahead
    fake = FakeStretch(world, obs_port=0, action_port=0, state_port=0).start()
    server = LiveServer(stretch_console(tmp_path / "data", fake, memory=True, send_posture=False))
    try:
        home = httpx.get(f"{server.url}/api/backends/stretch").json()["memory_home"]
        _, b = browser
        page = b.new_context(viewport={"width": 1440, "height": 900}).new_page()
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.goto(server.url + "/console")
        poll(lambda: page.is_visible("#memory-card"), bool, 30, "memory card")
        assert page.input_value("#backend") == "stretch" and page.text_content("#memory-home") == home
        poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("Nothing yet"), 30, "empty")

        photo = encode(world.render(world.start_world, fake.tilt_rad)[0], "PNG")  # the pillar

        def robot_run(max_steps: str) -> str:
            resp = httpx.post(
                f"{server.url}/api/runs",
                files={"goal_image": ("g.png", photo, "image/png")},
                data={"backend": "stretch", "max_steps": max_steps},
            )
            assert resp.status_code == 201, resp.text
            run_id = resp.json()["id"]
            poll(
                lambda: httpx.get(f"{server.url}/api/runs/{run_id}").json()["status"], lambda s: s in FINAL, 300, "end"
            )
            return run_id

        first = robot_run("1")
        poll(lambda: page.text_content("#memory-words") or "", lambda t: t.startswith("1 request"), 30, "memory words")
        items = page.locator("#memory-objects li").all_text_contents()
        assert len(items) == 1 and items[0].startswith("request 1: ") and items[0].endswith("Find it again"), items

        # "Find it again" on the robot: from memory, with the first request's photo (stopped after a step)
        page.click("#memory-objects li[data-request='1'] button.memory-again")
        poll(lambda: page.is_enabled("#stop"), bool, 60, "run from memory active")
        problems = check_page(page)  # while the page shows the run active
        assert not problems, problems
        again = httpx.get(f"{server.url}/api/runs").json()["runs"][0]
        assert again["goal"]["from_run"] == first and again["options"]["home"] == home, again
        # stopped after its first step, so that it is the run that last left the robot (a stop
        # before any step leaves the memory's last pose, and the drop's words, with the first run)
        poll(
            lambda: httpx.get(f"{server.url}/api/runs/{again['id']}").json()["n_steps"], lambda n: n >= 1, 60, "a step"
        )
        page.click("#stop")
        poll(
            lambda: httpx.get(f"{server.url}/api/runs/{again['id']}").json()["status"], lambda s: s in FINAL, 300, "end"
        )

        left = fake.pose_world
        fake.push_base(Pose2D(left.x_m, left.y_m - 1.0, left.yaw_rad))  # moved by hand between runs
        pushed = robot_run("1")
        # the pushed run's own memory, from nothing, with the drop's words (the page shows the drop
        # first, at the run's start, and its own request once the run has ended)
        words = poll(
            lambda: page.text_content("#memory-words") or "",
            lambda t: "Dropped" in t and t.startswith("1 request"),
            30,
            "the drop and the pushed run's own request",
        )
        assert f"(run {pushed}): the robot starts 1.00 m and 0 deg from where run {again['id']} left it" in words, words
        log = poll(
            lambda: page.text_content("#log") or "", lambda t: f"the memory of {home} is dropped" in t, 30, "log"
        )
        assert f"run {pushed}: the memory of {home} is dropped: the robot starts" in log
        problems = check_page(page)
        assert not problems, problems
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.locator("#memory-card").screenshot(path=str(ARTIFACTS / "memory_panel_robot.png"))
        assert not errors, errors
    finally:
        server.close()
        fake.close()
