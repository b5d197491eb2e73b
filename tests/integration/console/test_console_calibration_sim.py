"""Calibration from "your own photos" in a real browser, with simulator goal images standing in
for the photos (several views of each of three objects of a simulated home) and the
deployment's real matcher (XFeat + LighterGlue)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from tests.helpers.console_live import ARTIFACTS, HOME_SEED, LiveServer, poll

pytestmark = pytest.mark.browser

VIEWS = 3


@pytest.fixture(scope="module")
def photo_sets(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[str, list[Path]]]:
    from console.sim_adapter import _world
    from sim.goals import sample_goal_images

    out = tmp_path_factory.mktemp("photos")
    world = _world(HOME_SEED, 3)
    try:
        sets = []
        for inst in world.home.instances:
            images = sample_goal_images(world, inst.object_id, VIEWS, (HOME_SEED, inst.object_id, 7))
            if len(images) < VIEWS:
                continue
            paths = []
            for v, goal in enumerate(images):
                path = out / f"{inst.category.replace(' ', '_')}-{inst.object_id}-{v}.jpg"
                Image.fromarray(goal.rgb).save(path, quality=90)
                paths.append(path)
            sets.append((f"{inst.category} {inst.object_id}", paths))
            if len(sets) == 3:
                break
    finally:
        world.close()
    assert len(sets) == 3, "home 0 should have three photographable instances"
    return sets


def test_calibrate_page_with_simulator_photos(browser, live_console: LiveServer, photo_sets) -> None:
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    context = b.new_context(viewport={"width": 1000, "height": 1200})
    page = context.new_page()
    try:
        page.goto(live_console.url + "/calibrate")
        page.wait_for_selector("#in-force:text-matches('In force now')")
        page.select_option("#deployment", "stretch")
        page.click("#add-object")  # a third object
        for k, (name, paths) in enumerate(photo_sets):
            page.fill(f"#object-name-{k}", name)
            page.dispatch_event(f"#object-name-{k}", "change")
            page.set_input_files(f"#object-files-{k}", [str(x) for x in paths])
        page.wait_for_selector("#run:not([disabled])")
        assert "9 photos: 9 same-object pairs, 27 different-object pairs" in page.inner_text("#pairs-note")
        page.click("#run")
        page.wait_for_selector("#result-card:not([hidden])", timeout=600_000)
        proposal = page.inner_text("#proposal")
        assert (
            "Proposed tau" in proposal
            and "of 9 same-object pairs" in proposal
            and "of 27 different-object pairs" in proposal
        )
        assert page.locator("#curves-svg path").count() == 2  # PR and F curves drawn
        page.screenshot(path=str(ARTIFACTS / "calibrate.png"), full_page=True)
        page.click("#save")
        page.wait_for_selector("#saved:text-matches('now uses tau')", timeout=30_000)
        saved = json.loads((live_console.console.data_dir / "calibration" / "stretch.json").read_text())
        assert saved["matcher"] == "xfeat_lighterglue" and saved["same_pairs"] == 9 and saved["different_pairs"] == 27
        assert saved["tau"] > 0 and saved["photos"] == 9
        status = poll(lambda: page.inner_text("#in-force"), lambda t: "your photos" in t, 30, "in force")
        assert f"{saved['tau']:.1f}" in status
        job = live_console.console.calibrator.get(saved["source"].rsplit(" ", 1)[-1])
        print(f"calibration of {job.view()['photos']} photos ({9 + 27} pairs): {job.seconds:.1f} s")
    finally:
        context.close()
