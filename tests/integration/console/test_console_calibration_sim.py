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


def _contrast(fg: str, bg: str) -> float:
    """WCAG contrast ratio of two CSS ``rgb(...)`` colours."""

    def luminance(css: str) -> float:
        r, g, b = (int(float(v)) / 255 for v in css[css.index("(") + 1 : css.index(")")].split(",")[:3])
        lin = [c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4 for c in (r, g, b)]
        return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]

    hi, lo = sorted((luminance(fg), luminance(bg)), reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def test_calibrate_page_with_simulator_photos(browser, live_console: LiveServer, photo_sets) -> None:
    p, b = browser
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    context = b.new_context(viewport={"width": 1000, "height": 1200})
    page = context.new_page()
    try:
        page.goto(live_console.url + "/calibrate")
        page.wait_for_selector("#in-force:text-matches('In force now')")
        # the header's idle badge (app.css), on this page's style sheet: readable (WCAG AA, 4.5:1)
        colours = page.evaluate(
            """() => { const h = document.createElement('header'); h.className = 'bar';
            h.innerHTML = '<span class="badge">idle</span>'; document.body.append(h);
            const s = getComputedStyle(h.firstChild); const out = [s.color, s.backgroundColor]; h.remove(); return out; }"""
        )
        assert _contrast(*colours) >= 4.5, colours
        # a console with only the simulator calibrates the simulator by default
        assert list(live_console.console.providers) == ["sim"]
        assert page.input_value("#deployment") == "sim"
        # a disabled button says why, in words tied to it
        assert page.is_disabled("#run") and page.get_attribute("#run", "aria-describedby") == "run-why"
        assert "at least 2 different objects" in page.inner_text("#run-why") and page.is_visible("#run-why")
        page.select_option("#deployment", "stretch")
        page.click("#add-object")  # a third object
        for k, (name, paths) in enumerate(photo_sets):
            page.fill(f"#object-name-{k}", name)
            page.dispatch_event(f"#object-name-{k}", "change")
            page.set_input_files(f"#object-files-{k}", [str(x) for x in paths])
        page.wait_for_selector("#run:not([disabled])")
        assert page.inner_text("#run-why") == ""
        assert "9 photos: 9 same-object pairs, 27 different-object pairs" in page.inner_text("#pairs-note")
        # a photo can be removed (the button is named after it), and chosen again
        first_name, first_paths = photo_sets[0]
        page.click(f"#object-thumbs-0 button[aria-label='Remove {first_paths[0].name} from {first_name}']")
        assert page.locator("#object-thumbs-0 img").count() == 2 and page.is_disabled("#run")
        assert f"at least 3 photos: {first_name} has 2" in page.inner_text("#run-why")
        page.set_input_files("#object-files-0", [str(first_paths[0])])
        page.wait_for_selector("#run:not([disabled])")
        assert "9 photos: 9 same-object pairs" in page.inner_text("#pairs-note")
        page.click("#run")
        page.wait_for_selector("#status:text-matches('Extracting|Matching|Done')")
        # a reload while the job runs: the page finds the job again and shows its result
        page.reload()
        page.wait_for_selector("#result-card:not([hidden])", timeout=600_000)
        assert page.input_value("#deployment") == "stretch"
        assert page.inner_text("#status") == "Done: every pair scored."  # was "done: done"
        proposal = page.inner_text("#proposal")
        assert (
            "Proposed tau" in proposal
            and "of 9 same-object pairs" in proposal
            and "of 27 different-object pairs" in proposal
        )
        assert page.locator("#curves-svg path").count() == 2  # PR and F curves drawn
        # what saving changes, and the pairs behind it
        change = page.inner_text("#change")
        assert "from 75.3 (the packaged simulator calibration" in change and "9 same-object pairs" in change, change
        assert page.locator("#pairs-table tr").count() == 1 + 36
        assert page.inner_text("#problems") == "" and page.is_enabled("#save"), page.inner_text("#problems")
        page.screenshot(path=str(ARTIFACTS / "calibrate.png"), full_page=True)
        page.click("#save")
        page.wait_for_selector("#saved:text-matches('now uses tau')", timeout=30_000)
        assert "it used 75.3" in page.inner_text("#saved")
        assert page.is_disabled("#save") and "in force now" in page.inner_text("#save-why")
        saved = json.loads((live_console.console.data_dir / "calibration" / "stretch.json").read_text())
        assert saved["matcher"] == "xfeat_lighterglue" and saved["same_pairs"] == 9 and saved["different_pairs"] == 27
        assert saved["tau"] > 0 and saved["photos"] == 9
        status = poll(lambda: page.inner_text("#in-force"), lambda t: "your photos" in t, 30, "in force")
        assert f"{saved['tau']:.1f}" in status
        job = live_console.console.calibrator.get(saved["source"].rsplit(" ", 1)[-1])
        print(
            f"calibration of {job.view()['photos']} photos ({9 + 27} pairs): tau {saved['tau']:.1f}, {job.seconds:.1f} s"
        )
        # ...and the save can be undone from the page
        assert "Undo puts back tau 75.3" in page.inner_text("#undo-note")
        page.click("#undo")
        page.wait_for_selector("#undo-note:text-matches('Undone')", timeout=30_000)
        poll(lambda: page.inner_text("#in-force"), lambda t: "packaged" in t, 30, "packaged tau back")
        assert not (live_console.console.data_dir / "calibration" / "stretch.json").exists()
        assert page.is_hidden("#undo-box") and page.is_enabled("#save")
    finally:
        context.close()
