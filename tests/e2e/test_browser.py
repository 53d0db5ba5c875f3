"""The web page in headless Chromium: upload, watch progress, play the orbit, see the masks
next to the matched silhouettes, screenshot (wide and narrow)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cadnerf_core.job_warnings import too_small_warning
from cadnerf_core.jobnames import photo_file_name
from tests.configs import TINY_PRESET
from tests.e2e.pages import CHROMIUM, LAUNCH_ARGS, TINY_CONFIG_SCRIPT, progress_samples

pytestmark = [pytest.mark.slow, pytest.mark.browser]


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_upload_progress_video_and_screenshot(live_service, photo_set: list[Path],
                                              tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 1400})
            page.add_init_script(TINY_CONFIG_SCRIPT)
            page.goto(live_service.url, timeout=30_000)
            page.wait_for_selector(f"#preset option[value={TINY_PRESET}]", state="attached")
            page.set_input_files("#photos", [str(p) for p in photo_set])
            assert page.locator("#thumbs li").count() == len(photo_set)
            assert page.locator("#thumbs li .order").all_inner_texts() == [
                str(i + 1) for i in range(len(photo_set))]
            page.select_option("#preset", TINY_PRESET)
            # A box looks alike walked either way round: the photographer says which way.
            page.select_option("#walk", "cw")
            page.check("#any-order")  # the order searched for, as when the user cannot tell
            # The renders carry no EXIF: their focal length (40 degrees across a square photo
            # is 42 mm in 35 mm terms) given in the optional part of the form.
            page.click("details summary")
            page.fill("#focal", "42")
            page.click("#submit")
            page.wait_for_selector("#status", state="visible", timeout=30_000)
            widths = progress_samples(page)
            page.wait_for_selector("#result", state="visible", timeout=300_000)
            duration = page.wait_for_function(
                "() => { const v = document.getElementById('orbit');"
                " return v.readyState >= 1 && v.duration > 0 ? v.duration : null; }",
                timeout=60_000).json_value()
            assert duration > 0
            assert max(widths) > 0 and widths == sorted(widths)  # the bar moved forward
            assert page.locator("#matches tbody tr").count() == len(photo_set)
            placed = page.eval_on_selector_all(  # how each camera was placed, and how sure
                "#matches tbody tr", "(rows) => rows.map((r) => r.cells[5].textContent)")
            assert any(text.split()[0] in ("points", "both", "outline") and text.endswith("%")
                       for text in placed), placed
            assert page.locator("#cameras circle").count() >= 2 + len(photo_set) - 2
            assert page.locator("#downloads a", has_text="mesh.glb").count() == 1
            assert "Retrieved CAD model" in page.inner_text("#model")
            assert "succeeded" in page.inner_text("#status-text")
            # The worker was given the direction (the DP alone reports a lead over the other
            # way, None only when told): nothing was guessed, so nothing is warned.
            retrieval = json.loads(max(live_service.settings.data_root.rglob("retrieval.json"),
                                       key=lambda p: p.stat().st_mtime).read_text())
            assert retrieval["direction"] == -1 and retrieval["direction_lead"] is None
            job_config = json.loads(max(live_service.settings.data_root.rglob("config.json"),
                                        key=lambda p: p.stat().st_mtime).read_text())
            assert job_config["retrieval"]["focal_35mm"] == 42.0
            assert job_config["retrieval"]["order"] == "any"
            walked = page.inner_text("#walk-order")  # the order used, around the cameras
            assert walked.startswith("Walking order:")
            numbers = walked.split(":")[1].replace("\u2192", " ").split()
            assert len(numbers) >= 2 and len(set(numbers)) == len(numbers)
            assert set(numbers) <= {str(i + 1) for i in range(len(photo_set))}
            # Four 64 px renders are too small to match: the one warning names them and says
            # the cameras come from silhouettes alone (direction and field of view were told,
            # so neither is warned).
            warned = page.locator("#warnings li").all_inner_texts()
            stored = [photo_file_name(i, p.name, "png") for i, p in enumerate(photo_set)]
            assert warned == [too_small_warning(stored)]
            _check_masks(page, len(photo_set))
            page.wait_for_timeout(500)
            # A test writes no tracked file: the screenshot goes to a temporary folder.
            shot = tmp_path / "web_page.png"
            page.screenshot(path=str(shot), full_page=True)
            assert shot.stat().st_size > 0
            page.set_viewport_size({"width": 380, "height": 800})  # a phone: nothing sideways
            assert page.evaluate("() => document.documentElement.scrollWidth") <= 380
            width = page.evaluate("() => document.querySelector('#mask-gallery img.overlay')"
                                  ".getBoundingClientRect().width")
            assert 0 < width < 380
        finally:
            browser.close()


def _check_masks(page, n_photos: int) -> None:  # type: ignore[no-untyped-def]
    """Each photo's overlay and matched silhouette load as images, with the mask's source."""
    page.wait_for_function(
        "() => { const images = [...document.querySelectorAll('#mask-gallery img')];"
        " return images.length > 0 && images.every((i) => i.complete); }", timeout=30_000)
    sizes = page.evaluate("() => [...document.querySelectorAll('#mask-gallery img.overlay')]"
                          ".map((i) => i.naturalWidth)")
    assert len(sizes) == n_photos and all(w > 0 for w in sizes), sizes
    silhouettes = page.evaluate("() => [...document.querySelectorAll('#mask-gallery "
                                "img.silhouette')].map((i) => i.naturalWidth)")
    assert silhouettes and all(w > 0 for w in silhouettes), silhouettes
    captions = page.locator("#mask-gallery .mask-caption").all_inner_texts()
    assert len(captions) == n_photos and all("mask: alpha" in c for c in captions), captions
