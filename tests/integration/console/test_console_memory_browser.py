"""The console page's memory panel (issue 31) in a real headless Chromium, with the real
simulator and agent: empty before the first run in a home, its map and known objects (with the
goal photo each was asked with) after one, "Find it again" starts a run from memory with that
photo, and Forget empties it."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers.console_live import ARTIFACTS, LiveServer, poll, sim_console

pytestmark = pytest.mark.browser

FINAL = ("finished", "stopped", "failed", "interrupted")


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
    assert f"{memory['keyframes']} remembered views" in (page.text_content("#memory-words") or "")
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
    problems = check_page(page)
    assert not problems, problems
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.locator("#memory-card").screenshot(path=str(ARTIFACTS / "memory_panel.png"))

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
