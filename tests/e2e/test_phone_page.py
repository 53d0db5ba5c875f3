"""The web page on a phone (390 px, touch) and on a desktop, in headless Chromium against the live
service: take a photo with the camera input and choose the rest, reorder one by pointer (touch
on the phone) and one by keyboard, submit, see progress move and the orbit play, download the
results; nothing wider than the screen on any step; the CPU server's preset preselected with
the expected times of the ETA table; an axe-core scan without serious or critical findings.

Set CADNERF_SCREENSHOT_DIR to keep the finished page; docs/web_page_phone.png comes from
``CADNERF_SCREENSHOT_DIR=docs .venv/bin/pytest tests/e2e/test_phone_page.py
-k "result and not desktop"``."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.state import DEFAULT_STAGE_SECONDS
from tests.configs import tiny_request_json
from tests.e2e.pages import (
    AXE,
    CHROMIUM,
    LAUNCH_ARGS,
    axe_missing_reason,
    axe_violations,
    progress_samples,
    tiny_config_script,
)

pytestmark = [pytest.mark.slow, pytest.mark.browser,
              pytest.mark.skipif(CHROMIUM is None,
                                 reason="chromium is not installed (apt-get install chromium)")]

PROFILES: dict[str, dict[str, Any]] = {
    "phone": {"viewport": {"width": 390, "height": 844}, "device_scale_factor": 3,
              "is_mobile": True, "has_touch": True},
    "desktop": {"viewport": {"width": 1280, "height": 900}},
}
# Phase three of the tiny job lasts long enough for the page's polls (one a second) to see the
# bar part way, not only empty and then full (a few seconds on two CPU cores).
PROGRESS_SCRIPT = tiny_config_script(phase3={"steps": 300})
LABEL_RULES = {"label", "button-name", "select-name", "input-button-name", "aria-input-field-name"}


def _duration(seconds: float) -> str:
    """The page's ``formatDuration`` (app/static/page.js): whole seconds under 90 s, whole
    minutes under 90 min, else hours to one decimal; JavaScript's Math.round rounds halves up."""
    def js_round(x: float) -> float:
        return math.floor(x + 0.5)

    s = max(0.0, seconds)
    if s < 90:
        return f"about {js_round(s):.0f} s"
    if s < 90 * 60:
        return f"about {js_round(s / 60):.0f} min"
    return f"about {js_round(s / 360) / 10:g} h"


def _fits(page: Any, step: str) -> None:
    """Nothing on the page is wider than the screen."""
    width, inner = page.evaluate(
        "() => [document.documentElement.scrollWidth, window.innerWidth]")
    assert width <= inner, f"{step}: the page is {width} px wide on a {inner} px screen"


def _names(page: Any) -> list[str]:
    return page.locator("#thumbs li .name").all_inner_texts()  # type: ignore[no-any-return]


def _center(page: Any, selector: str) -> tuple[float, float]:
    box = page.locator(selector).bounding_box()
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


def _drag(page: Any, profile: str, source: str, target: str) -> None:
    """Drag ``source`` onto ``target``: a finger on the phone (touch events through the
    DevTools protocol, which Chromium turns into pointer events), the mouse on the desktop."""
    (x0, y0), (x1, y1) = _center(page, source), _center(page, target)
    steps = [(x0 + (x1 - x0) * i / 10, y0 + (y1 - y0) * i / 10) for i in range(11)]
    if profile == "desktop":
        page.mouse.move(x0, y0)
        page.mouse.down()
        for x, y in steps[1:]:
            page.mouse.move(x, y)
        page.mouse.up()
        return
    cdp = page.context.new_cdp_session(page)
    for kind, points in [("touchStart", [steps[0]]), *[("touchMove", [s]) for s in steps[1:]],
                         ("touchEnd", [])]:
        cdp.send("Input.dispatchTouchEvent",
                 {"type": kind, "touchPoints": [{"x": x, "y": y} for x, y in points]})
    cdp.detach()


def _check_presets(page: Any, url: str) -> None:
    """The CPU server's default (preview) is preselected; every preset shows its expected time:
    what /v1/info says, which is the ETA table's until a job of it was measured here."""
    info = httpx.get(f"{url}/v1/info", timeout=10).json()
    assert info["device"] == "cpu" and info["default_preset"] == "preview"
    assert page.input_value("#preset") == "preview"
    options = page.eval_on_selector_all(
        "#preset option", "(os) => os.map((o) => [o.value, o.textContent, o.dataset.seconds])")
    assert [o[0] for o in options] == info["presets"]
    for name, text, seconds in options:
        time_info = info["preset_times"][name]
        if time_info["seconds"] is None:  # the tests' own preset: no ETA table, none run yet
            assert name not in DEFAULT_STAGE_SECONDS["cpu"] and not time_info["measured"]
            assert seconds == "" and text == f"{name} \u2013 not measured yet", (name, text)
            continue
        assert float(seconds) == time_info["seconds"], (name, seconds, time_info)
        if not time_info["measured"]:
            assert time_info["seconds"] == sum(DEFAULT_STAGE_SECONDS["cpu"][name].values())
        assert text == f"{name} \u2013 {_duration(time_info['seconds'])}", (text, time_info)
    preview = info["preset_times"]["preview"]
    shown = page.inner_text("#preset-time")
    assert shown.startswith(f"preview: {_duration(preview['seconds'])} a job"), (shown, preview)
    assert "without a GPU" in shown, shown


def _reorder(page: Any, profile: str, names: list[str]) -> list[str]:
    """Move photo 1 onto photo 3 by pointer, then photo 3 one later by keyboard; the order then
    is a rotation of the walk, which retrieval accepts (a walk may start anywhere)."""
    _drag(page, profile, "#thumbs li:nth-child(1) img", "#thumbs li:nth-child(3) img")
    moved = [names[1], names[2], names[0], names[3]]
    assert _names(page) == moved
    assert page.locator("#thumbs li .order").all_inner_texts() == ["1", "2", "3", "4"]
    assert page.get_attribute("#thumbs li:nth-child(3) img", "alt") == f"Photo 3: {names[0]}"
    page.focus("#thumbs li:nth-child(3) button.later")
    page.keyboard.press("Enter")
    rotated = [names[1], names[2], names[3], names[0]]
    assert _names(page) == rotated
    # The keyboard stays with the photo it moved (now last: its "later" button is disabled).
    assert page.evaluate("() => document.activeElement.closest('li').dataset.index") == "3"
    assert page.evaluate("() => document.activeElement.classList.contains('earlier')")
    assert f"{names[0]} is now photo 4 of 4" in page.inner_text("#order-status")
    return rotated


def _submit_in_view(page: Any) -> None:
    """The submit button is on the screen (not under anything) without scrolling."""
    top, bottom, inner, on_top = page.evaluate(
        "() => { const b = document.getElementById('submit').getBoundingClientRect();"
        " const hit = document.elementFromPoint(b.left + b.width / 2, b.top + b.height / 2);"
        " return [b.top, b.bottom, window.innerHeight, hit && hit.id === 'submit']; }")
    assert top >= 0 and bottom <= inner and on_top, (top, bottom, inner)


def _check_result(page: Any, order: list[str]) -> None:
    """The orbit plays inline, muted and looping; table, cameras and video fit; downloads load."""
    page.wait_for_function(
        "() => { const v = document.getElementById('orbit');"
        " return v.duration > 0 && !v.paused && v.played.length > 0; }", timeout=60_000)
    assert page.evaluate("() => { const v = document.getElementById('orbit');"
                         " return [v.muted, v.loop, v.playsInline]; }") == [True, True, True]
    assert [row[1] for row in page.eval_on_selector_all(
        "#matches tbody tr", "(rows) => rows.map((r) => [...r.cells].map((c) => c.textContent))")
    ] == order  # the photos went in the order the page showed
    overflow = page.evaluate(
        "() => [...document.querySelectorAll('#matches, #cameras, #orbit, .table-scroll')]"
        ".filter((e) => e.getBoundingClientRect().right > window.innerWidth"
        " || e.scrollWidth > e.clientWidth + 1).map((e) => e.id || e.className)")
    assert overflow == []
    links = page.eval_on_selector_all("#downloads a", "(as) => as.map((a) => a.href)")
    assert any(link.endswith("mesh.glb") for link in links)
    for link in links:
        response = page.request.get(link)
        assert response.ok and len(response.body()) > 0, link


@pytest.mark.parametrize("profile", ["phone", "desktop"])
def test_photos_reorder_submit_and_result(live_service, photo_set: list[Path], tmp_path: Path,
                                          profile: str) -> None:
    from playwright.sync_api import sync_playwright

    names = [p.name for p in photo_set]
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            page = browser.new_context(**PROFILES[profile]).new_page()
            page.add_init_script(PROGRESS_SCRIPT)
            page.goto(live_service.url, timeout=30_000)
            page.wait_for_selector("#preset option", state="attached")
            # The mobile viewport meta: laid out at the screen's width, not 980 px shrunk to fit.
            width = PROFILES[profile]["viewport"]["width"]
            assert page.evaluate("() => window.innerWidth") == width
            _fits(page, "page load")
            _check_presets(page, live_service.url)
            camera = page.locator("#camera")
            assert camera.get_attribute("capture") == "environment"
            assert camera.get_attribute("accept") == "image/*"
            assert camera.get_attribute("multiple") is None  # one photo a time
            assert {"image/heic", "image/heif"} <= set(page.get_attribute("#photos", "accept")
                                                       .split(","))
            guide = " ".join(page.inner_text("#camera-guide").split())
            for words in ("Walk round the object", "6 to 8 photos", "keep all of it in frame",
                          "the zoom the same"):
                assert words in guide, (words, guide)
            page.set_input_files("#camera", str(photo_set[0]))
            assert _names(page) == names[:1]
            _fits(page, "camera photo")
            page.set_input_files("#photos", [str(p) for p in photo_set[1:]])
            assert _names(page) == names
            _fits(page, "photos chosen")
            order = _reorder(page, profile, names)
            _fits(page, "photos reordered")
            page.select_option("#walk", "cw")  # a box looks alike walked either way round
            page.click("details summary")
            page.fill("#focal", "42")  # the renders carry no EXIF (40 degrees across: 42 mm)
            _fits(page, "options open")
            page.evaluate("() => window.scrollTo(0, 0)")
            _submit_in_view(page)
            if profile == "phone":
                page.tap("#submit")
            else:
                page.click("#submit")
            page.wait_for_selector("#status", state="visible", timeout=30_000)
            states: list[str] = []

            def fits_while_running() -> None:
                _fits(page, "progress")
                states.append(page.inner_text("#status-text").split(" \u00b7 ")[0])

            widths = progress_samples(page, fits_while_running)
            page.wait_for_selector("#result", state="visible", timeout=300_000)
            assert "running" in states, states  # the width was checked while the job ran
            # The bar moved forward, and was seen part way, not only empty and then full.
            assert widths == sorted(widths) and any(0 < w < 100 for w in widths), widths
            _check_result(page, order)
            _fits(page, "result")
            # The whole page in one picture at the device's width: a screen as tall as the page,
            # so the submit bar sits where it belongs rather than stuck to a screen's foot.
            height = page.evaluate("() => document.documentElement.scrollHeight")
            page.set_viewport_size({"width": width, "height": height})
            page.wait_for_timeout(300)
            folder = Path(os.environ.get("CADNERF_SCREENSHOT_DIR") or tmp_path)
            shot = folder / f"web_page_{profile}.png"
            page.screenshot(path=str(shot), full_page=True, scale="css")
            assert shot.stat().st_size > 0
        finally:
            browser.close()


@pytest.mark.parametrize("width", [360, 430])
def test_the_smallest_and_largest_phones_fit(live_service, photo_set: list[Path],
                                             width: int) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            page = browser.new_context(viewport={"width": width, "height": 740}, is_mobile=True,
                                       has_touch=True, device_scale_factor=3).new_page()
            page.goto(live_service.url, timeout=30_000)
            page.wait_for_selector("#preset option", state="attached")
            assert page.evaluate("() => window.innerWidth") == width
            _fits(page, "page load")
            eight = [str(p) for p in photo_set] * 2  # a full walk of 8 photos
            page.set_input_files("#photos", eight)
            assert page.locator("#thumbs li").count() == len(eight)
            page.click("details summary")
            _fits(page, "8 photos, options open")
            page.evaluate("() => window.scrollTo(0, 0)")
            _submit_in_view(page)
            page.evaluate("() => window.scrollTo(0, document.documentElement.scrollHeight)")
            _submit_in_view(page)
            page.focus("#thumbs li:nth-child(8) button.earlier")
            page.keyboard.press("Enter")
            assert page.locator("#thumbs li .order").all_inner_texts() == [
                str(i + 1) for i in range(len(eight))]
            assert page.get_attribute("#thumbs li:nth-child(7) img", "alt") == (
                f"Photo 7: {photo_set[-1].name}")
        finally:
            browser.close()


def _finished_job(url: str, photo_set: list[Path]) -> str:
    """A tiny job sent as an API client would, waited for until it succeeded."""
    files = [("images", (p.name, p.read_bytes(), "image/png")) for p in photo_set]
    response = httpx.post(f"{url}/v1/jobs", files=files,
                          data={"config": tiny_request_json(retrieval={"walk": "cw"})},
                          timeout=60)
    assert response.status_code == 202, response.text
    job_id = str(response.json()["id"])
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        state = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10).json()["state"]
        if state in ("succeeded", "failed", "cancelled"):
            assert state == "succeeded"
            return job_id
        time.sleep(0.5)
    raise AssertionError("the job did not finish")


@pytest.mark.skipif(axe_missing_reason() is not None, reason=str(axe_missing_reason()))
@pytest.mark.parametrize("profile", ["phone", "desktop"])
def test_axe_finds_nothing_serious_and_every_control_is_labelled(
        live_service, photo_set: list[Path], profile: str) -> None:
    from playwright.sync_api import sync_playwright

    assert AXE.is_file()
    job_id = _finished_job(live_service.url, photo_set)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            page = browser.new_context(**PROFILES[profile]).new_page()
            page.goto(f"{live_service.url}/?job={job_id}", timeout=30_000)
            page.wait_for_selector("#preset option", state="attached")
            page.wait_for_selector("#result", state="visible", timeout=60_000)
            page.set_input_files("#photos", [str(p) for p in photo_set])
            page.click("details summary")  # every control of the form, result and progress
            found = axe_violations(page)
            bad = [v for v in found if v["impact"] in ("serious", "critical")
                   or v["id"] in LABEL_RULES]
            assert bad == [], bad
        finally:
            browser.close()
