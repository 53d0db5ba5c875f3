"""The result page's screenshot (``docs/result_viewer.png``) from a real photo set.

Starts ``cadnerf serve`` on a private data root in a temporary folder (its own embedded Redis and
worker, on the CPU, with ``library_data/build``), submits ``../shared/eval/photos/<set>/images``
with their masks and preset ``preview`` over HTTP, waits for the job to succeed, opens the result
page in headless Chromium at desktop width, waits for the 3D viewer to load the textured mesh,
turns it by a drag and screenshots ``#result``.

Run: ``.venv/bin/python -m benchmarks.shoot_result_page [--out docs/result_viewer.png]
[--set raydiffusion_robot]`` (a preview job takes about 5 minutes on two busy cores).
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from app.client import JobClient
from app.routes.pages import VENDOR
from benchmarks.harness import DOCS, EVAL_ROOT, LIBRARY_DIR, PHOTOS, ROOT
from cadnerf_cli.demo_cmd import StatusPrinter
from tests.e2e.pages import CHROMIUM, WEBGL_LAUNCH_ARGS, drag_across
from tests.e2e.test_serve import _ready_workers, _start_serve, _stop

VIEWPORT_WIDTH, VIEWPORT_HEIGHT = 1280, 900  # a laptop's browser window


def _photos(set_name: str) -> tuple[list[Path], list[Path]]:
    """The set's photos and one mask per photo (same stem, PNG), in name order."""
    folder = PHOTOS / set_name
    photos = sorted(p for p in (folder / "images").iterdir()
                    if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    masks = [folder / "masks" / f"{p.stem}.png" for p in photos]
    if not photos or not all(m.is_file() for m in masks):
        sys.exit(f"error: {folder} needs images/ and one masks/<name>.png per photo")
    return photos, masks


def run_job(url: str, photos: list[Path], masks: list[Path]) -> tuple[str, float]:
    """Submit the photos and masks with preset ``preview``; the job's id and wall seconds."""
    client = JobClient(url)
    try:
        started = time.monotonic()
        job = client.submit(photos, masks, config={"preset": "preview"})
        print(f"job {job['id']}: {len(photos)} photos with masks, preset preview")
        final = client.follow(job["id"], on_update=StatusPrinter(), poll_s=2.0,
                              timeout_s=3600)
        wall_s = time.monotonic() - started
    finally:
        client.close()
    if final["state"] != "succeeded":
        sys.exit(f"error: job {final['state']}: {final.get('error')}")
    return job["id"], wall_s


def _evaluate(page: Any, script: str) -> Any:
    return page.evaluate(f"() => {{ const v = document.getElementById('mesh-viewer'); {script} }}")


def shoot(url: str, job_id: str, out: Path) -> dict[str, Any]:
    """Open the job's page, turn the mesh by a drag, screenshot ``#result`` to ``out``; what
    the page reported (the viewer's turn in radians, failed requests, console errors)."""
    from playwright.sync_api import sync_playwright

    errors: list[str] = []
    failed: list[str] = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=WEBGL_LAUNCH_ARGS)
        try:
            page = browser.new_page(viewport={"width": VIEWPORT_WIDTH, "height": VIEWPORT_HEIGHT})
            # A console error names its address: the browser's own requests (the tab icon) come
            # to no response handler.
            page.on("console", lambda m: errors.append(f"{m.text} ({m.location.get('url')})")
                    if m.type == "error" else None)
            page.on("response", lambda r: failed.append(f"{r.status} {r.url}")
                    if r.status >= 400 else None)
            page.goto(f"{url}/?job={job_id}", timeout=60_000)
            page.wait_for_selector("#result", state="visible", timeout=60_000)
            page.wait_for_function("() => document.getElementById('orbit').duration > 0",
                                   timeout=60_000)
            # The orbit at its first frame (it plays on its own otherwise).
            page.evaluate("() => { const v = document.getElementById('orbit'); v.pause();"
                          " v.currentTime = 0; }")
            page.wait_for_function("() => document.getElementById('mesh-viewer')?.loaded",
                                   timeout=120_000)
            page.locator("#mesh-viewer").scroll_into_view_if_needed()
            before = _evaluate(page, "return v.getCameraOrbit().theta;")
            drag_across(page, "#mesh-viewer", 0.7, 0.45)
            page.wait_for_timeout(1500)  # the viewer eases to its new orbit
            turned = float(_evaluate(page, "return v.getCameraOrbit().theta;") - before)
            out.parent.mkdir(parents=True, exist_ok=True)
            page.locator("#result").screenshot(path=str(out))
        finally:
            browser.close()
    return {"turned_rad": round(turned, 2), "failed_requests": failed,
            "console_errors": errors}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DOCS / "result_viewer.png")
    parser.add_argument("--set", dest="set_name", default="raydiffusion_robot",
                        help="a folder of ../shared/eval/photos")
    args = parser.parse_args()
    if not EVAL_ROOT.is_dir():
        sys.exit(f"error: {EVAL_ROOT} is absent: the real photo sets live there (shared/eval "
                 "beside "
                 "the repository); nothing was shot")
    if CHROMIUM is None:
        sys.exit("error: chromium is not installed (apt-get install chromium)")
    if not (ROOT / "node_modules" / VENDOR["model-viewer.js"]).is_file():
        sys.exit("error: @google/model-viewer is not installed: run `npm ci` (or `make setup`)")
    photos, masks = _photos(args.set_name)
    with tempfile.TemporaryDirectory(prefix="cadnerf-shot-") as tmp:
        serve, url, log = _start_serve(Path(tmp), LIBRARY_DIR)
        try:
            _ready_workers(url, 300)
            job_id, wall_s = run_job(url, photos, masks)
            print(f"job wall time (submit to success): {wall_s:.0f} s")
            report = shoot(url, job_id, args.out.resolve())
        finally:
            _stop(serve, log, signal.SIGTERM)
    print(f"mesh turned {report['turned_rad']} rad by the drag; screenshot: {args.out}")
    for request in report["failed_requests"]:
        print(f"page request failed: {request}")
    for error in report["console_errors"]:
        print(f"page console error: {error}")


if __name__ == "__main__":
    main()
