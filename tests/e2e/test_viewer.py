"""Turn it yourself, in headless Chromium: a finished job's page spins the orbit video when it
is dragged, and shows the textured mesh in <model-viewer> served by our own server."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest

from tests.configs import tiny_request_json
from tests.e2e.pages import CHROMIUM, WEBGL_LAUNCH_ARGS, drag_across

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def _viewer_installed(service) -> bool:  # type: ignore[no-untyped-def]
    from app.routes.pages import VENDOR

    return (service.settings.web_modules / VENDOR["model-viewer.js"]).is_file()


def _finished_job(url: str, photos: list[Path]) -> str:
    """Submit the photos with the tiny config over HTTP and wait until the job succeeded."""
    files = [("images", (p.name, p.read_bytes(), "image/png")) for p in photos]
    config = tiny_request_json(retrieval={"walk": "cw", "focal_35mm": 42.0})
    response = httpx.post(f"{url}/v1/jobs", files=files, data={"config": config}, timeout=60)
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        state = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()["state"]
        if state in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.5)
    assert state == "succeeded", httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).text
    return job_id


def test_vendor_module_is_served_only_when_installed(live_service) -> None:
    response = httpx.get(f"{live_service.url}/vendor/model-viewer.js", timeout=30)
    if _viewer_installed(live_service):
        assert response.status_code == 200
        assert response.headers["content-type"].startswith("text/javascript")
    else:
        assert response.status_code == 404 and response.json()["code"] == "not_installed"
    assert httpx.get(f"{live_service.url}/vendor/../pyproject.toml", timeout=10).status_code == 404
    assert httpx.get(f"{live_service.url}/vendor/three.js", timeout=10).status_code == 404


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_drag_spins_the_orbit_and_the_mesh_turns(live_service, photo_set: list[Path],
                                                 tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    job_id = _finished_job(live_service.url, photo_set)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=WEBGL_LAUNCH_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 1400})
            # Every request the page makes must be answered, the browser's own included (the
            # tab icon: Playwright reports it only as a console error, with its address).
            missing: list[str] = []
            page.on("console", lambda m: missing.append(m.location.get("url", m.text))
                    if m.type == "error" and m.text.startswith("Failed to load resource")
                    else None)
            page.goto(f"{live_service.url}/?job={job_id}", timeout=30_000)
            page.wait_for_selector("#result", state="visible", timeout=60_000)
            page.wait_for_function("() => document.getElementById('orbit').duration > 0",
                                   timeout=60_000)
            box = page.locator("#orbit").bounding_box()
            assert box is not None
            page.evaluate("() => { const v = document.getElementById('orbit'); v.pause();"
                          " v.currentTime = 0; }")
            y = box["y"] + box["height"] * 0.4
            page.mouse.move(box["x"] + box["width"] * 0.6, y)
            page.mouse.down()
            page.mouse.move(box["x"] + box["width"] * 0.35, y, steps=5)
            page.mouse.up()
            assert page.evaluate("() => document.getElementById('orbit').paused")
            time_after = page.evaluate("() => document.getElementById('orbit').currentTime")
            duration = page.evaluate("() => document.getElementById('orbit').duration")
            # A quarter width to the left: a quarter turn forward.
            assert time_after == pytest.approx(0.25 * duration, abs=0.05 * duration)
            assert "drag across it" in page.inner_text("#orbit + figcaption")
            assert not missing, missing
            if not _viewer_installed(live_service):
                assert page.locator("model-viewer").count() == 0  # the fallback alone
                return
            page.wait_for_function("() => document.getElementById('mesh-viewer')?.loaded",
                                   timeout=60_000)
            # The job's mesh.usdz is the viewer's AR model (AR Quick Look on an iPhone).
            ios_src = page.get_attribute("#mesh-viewer", "ios-src") or ""
            assert ios_src.endswith("/mesh.usdz")
            assert page.get_attribute("#mesh-viewer", "ar") is not None
            before = page.evaluate("() => document.getElementById('mesh-viewer')"
                                   ".getCameraOrbit().theta")
            drag_across(page, "#mesh-viewer", 0.7, 0.3)
            page.wait_for_timeout(800)
            after = page.evaluate("() => document.getElementById('mesh-viewer')"
                                  ".getCameraOrbit().theta")
            assert abs(after - before) > 0.3  # radians: the user turned it
            shot = tmp_path / "result_viewer.png"
            page.locator("#result").screenshot(path=str(shot))
            assert shot.stat().st_size > 0
            assert not missing, missing
        finally:
            browser.close()
