"""The web page in headless Chromium against a fake API: polling that survives a 503 or a network
blip, skipped file types, photo-count checks, upload progress over XMLHttpRequest, the queue
position and ETA of a queued job, and a failed job's error_detail.

The fake API (a stdlib HTTP server) serves the real files of app/static and answers just enough of
`/v1` for the page; no Redis, worker or library is needed, so these tests are quick.
"""

from __future__ import annotations

import json
import re
import shutil
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

pytestmark = [pytest.mark.browser]

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "app" / "static"
CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists()
                                         else None)
LAUNCH_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
               "--disable-component-update", "--disable-sync"]
INFO = {"presets": ["fast", "test"], "default_preset": "test", "min_photos": 3, "max_photos": 10,
        "max_file_mb": 20.0, "max_total_mb": 200.0, "max_megapixels": 40.0, "min_side_px": 32}
JOB_PATH = re.compile(r"^/v1/jobs/([0-9a-f-]{36})(/result)?$")
CONTENT_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}

if CHROMIUM is None:
    pytest.skip("chromium is not installed (apt-get install chromium)", allow_module_level=True)


@dataclass
class FakeApi:
    """What the fake API received, and how far each job has got."""

    url: str = ""
    uploads: list[dict[str, Any]] = field(default_factory=list)
    polls: dict[str, int] = field(default_factory=dict)
    scripted: dict[str, dict[str, Any]] = field(default_factory=dict)  # job id -> fixed status
    lock: threading.Lock = field(default_factory=threading.Lock)


def _status(job_id: str, **fields: Any) -> dict[str, Any]:
    """A JobStatus body (app/schemas.py): queued at 0 % unless `fields` say otherwise."""
    return {"id": job_id, "state": "queued", "preset": "test", "n_photos": 3, "created_at": 0.0,
            "links": {"self": f"/v1/jobs/{job_id}", "result": f"/v1/jobs/{job_id}/result",
                      "web": f"/?job={job_id}"},
            "stage": None, "progress": 0.0, "eta_s": None, "queue_position": None,
            "started_at": None, "finished_at": None, "error": None, "error_detail": None} | fields


def _job(job_id: str, polls: int) -> dict[str, Any]:
    """Running at 40 % on the first poll, 80 % on the second, done from the third."""
    progress, state = {1: (0.4, "running"), 2: (0.8, "running")}.get(polls, (1.0, "succeeded"))
    return _status(job_id, state=state, stage="phase2" if state == "running" else None,
                   progress=progress, eta_s=30.0 if state == "running" else None)


def _result() -> dict[str, Any]:
    """A result in the API's one schema (``cadnerf_core.jobresult``), as its JSON."""
    from cadnerf_core.jobresult import JobResult, ModelRef, PhotoResult

    photos = [PhotoResult(index=i, name=f"photo{i}.png", discarded=False, iou=0.9,
                          azimuth=90.0 * i, elevation=10.0,
                          c2w=[[1, 0, 0, 2.0 * (i - 1)], [0, 1, 0, 0], [0, 0, 1, 2.0],
                               [0, 0, 0, 1]]) for i in range(3)]
    result = JobResult(model=ModelRef(id="mug", category="mug"), photos=photos,
                       artifacts=["mesh.glb"])
    return result.model_dump(mode="json")


def _handler(api: FakeApi) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - quiet
            pass

        def _send(self, status: int, body: bytes, content_type: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, payload: Any) -> None:
            self._send(status, json.dumps(payload).encode(), "application/json")

        def do_GET(self) -> None:  # noqa: N802 - http.server's naming
            path = self.path.split("?", 1)[0]
            if path == "/" or path.startswith("/static/"):
                file = STATIC / ("index.html" if path == "/" else path.removeprefix("/static/"))
                if file.is_file() and file.resolve().parent == STATIC.resolve():
                    self._send(200, file.read_bytes(), CONTENT_TYPES.get(file.suffix, "text/plain"))
                    return
            elif path == "/v1/info":
                self._json(200, INFO)
                return
            elif match := JOB_PATH.match(path):
                job_id = match.group(1)
                with api.lock:
                    if job_id in api.scripted and not match.group(2):
                        api.polls[job_id] = api.polls.get(job_id, 0) + 1
                        self._json(200, _status(job_id, **api.scripted[job_id]))
                        return
                    if job_id not in api.polls:
                        self._json(404, {"error": {"code": "not_found", "message": "no such job",
                                                   "hint": "check the id; jobs are deleted after "
                                                           "the retention period"}})
                        return
                    if match.group(2):
                        self._json(200, _result())
                        return
                    api.polls[job_id] += 1
                    self._json(200, _job(job_id, api.polls[job_id]))
                    return
            self._json(404, {"error": {"code": "not_found", "message": "not found"}})

        def do_POST(self) -> None:  # noqa: N802
            if self.path != "/v1/jobs":
                self._json(404, {"error": {"code": "not_found", "message": "not found"}})
                return
            body = self.rfile.read(int(self.headers.get("Content-Length", "0")))
            parts = re.findall(rb'name="([^"]+)"(?:; filename="([^"]*)")?', body)
            config = re.search(rb'name="config"\r\n\r\n(.*?)\r\n', body, re.S)
            images = [f.decode() for n, f in parts if n == b"images"]
            upload = {"authorization": self.headers.get("Authorization"), "bytes": len(body),
                      "content_type": self.headers.get("Content-Type", ""), "images": images,
                      "masks": [f.decode() for n, f in parts if n == b"masks"],
                      "config": json.loads(config.group(1)) if config else None}
            with api.lock:
                api.uploads.append(upload)
            if "bad.png" in images:
                self._json(422, {"error": {"code": "unreadable_image", "message": "not an image",
                                           "photo": "bad.png",
                                           "hint": "the file is truncated or damaged"}})
                return
            job_id = str(uuid.uuid4())
            with api.lock:
                api.polls[job_id] = 0
            self._json(202, _job(job_id, 1) | {"state": "queued", "progress": 0.0})

    return Handler


@pytest.fixture(scope="module")
def fake_api() -> Iterator[FakeApi]:
    api = FakeApi()
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(api))
    api.url = f"http://127.0.0.1:{server.server_address[1]}"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield api
    finally:
        server.shutdown()
        server.server_close()
        thread.join(10)


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=LAUNCH_ARGS)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture
def page(chromium: Any, fake_api: FakeApi) -> Iterator[Any]:
    context = chromium.new_context(viewport={"width": 1100, "height": 1200})
    page = context.new_page()
    page.set_default_timeout(15_000)
    page.goto(fake_api.url)
    page.wait_for_selector("#preset option[value=test]", state="attached")
    try:
        yield page
    finally:
        context.close()


def _png(name: str, size: int = 256) -> dict[str, Any]:
    """A file for set_input_files (the page checks the type, the fake API nothing)."""
    return {"name": name, "mimeType": "image/png", "buffer": b"\x89PNG\r\n\x1a\n" + bytes(size)}


def _submit_three(page: Any, size: int = 256) -> None:
    page.set_input_files("#photos", [_png(f"photo{i}.png", size) for i in range(3)])
    page.click("#submit")
    page.wait_for_selector("#status", state="visible")


def _fail_second_poll(page: Any, fake_api: FakeApi, fail: Any) -> list[str]:
    """Answer a job's second GET once with ``fail(route)``; pass everything else on. Returns
    the URLs that were failed (to check the failure was served)."""
    failed: list[str] = []

    def handler(route: Any) -> None:
        job_id = route.request.url.rsplit("/", 1)[1]
        if route.request.method == "GET" and fake_api.polls.get(job_id) == 1 and not failed:
            failed.append(route.request.url)
            fail(route)
        else:
            route.continue_()

    page.route("**/v1/jobs/*", handler)
    return failed


def test_poll_survives_one_503(page: Any, fake_api: FakeApi) -> None:
    """A 503 with Retry-After (Redis restarting) shows "reconnecting", then progress continues."""
    failed = _fail_second_poll(page, fake_api, lambda route: route.fulfill(
        status=503, headers={"Retry-After": "1"}, content_type="application/json",
        body=json.dumps({"error": {"code": "store_unavailable",
                                   "message": "the job store is unavailable",
                                   "hint": "try again in a few seconds"}})))
    _submit_three(page)
    notice = page.locator("#job-notice")
    notice.wait_for(state="visible")
    assert "reconnecting" in notice.inner_text().lower()
    assert "503" in notice.inner_text()
    assert "40%" in page.inner_text("#status-text")  # the last good answer stays on screen
    assert page.locator("#job-error").is_hidden()
    page.wait_for_selector("#result", state="visible")
    assert failed, "the fake 503 was never served"
    assert notice.is_hidden()
    assert "succeeded" in page.inner_text("#status-text")
    assert page.evaluate("() => document.getElementById('bar-fill').style.width") == "100%"
    assert page.locator("#job-error").is_hidden()
    assert page.locator("#matches tbody tr").count() == 3


def test_poll_survives_network_error(page: Any, fake_api: FakeApi) -> None:
    """A poll that gets no answer at all (fetch's TypeError) is retried after a back-off."""
    aborted = _fail_second_poll(page, fake_api, lambda route: route.abort("connectionreset"))
    _submit_three(page)
    notice = page.locator("#job-notice")
    notice.wait_for(state="visible")
    assert "cannot be reached" in notice.inner_text()
    page.wait_for_selector("#result", state="visible")
    assert aborted and notice.is_hidden()
    assert "succeeded" in page.inner_text("#status-text")


def test_poll_stops_on_unknown_job(page: Any, fake_api: FakeApi) -> None:
    """A 404 stops polling and says why (no endless retries)."""
    job_id = str(uuid.uuid4())
    requests: list[str] = []
    page.on("request", lambda request: requests.append(request.url)
            if request.url.endswith(f"/v1/jobs/{job_id}") else None)
    page.goto(f"{fake_api.url}/?job={job_id}")
    error = page.locator("#job-error")
    error.wait_for(state="visible")
    assert "Stopped following the job" in error.inner_text()
    assert "no such job" in error.inner_text()
    page.wait_for_timeout(2500)
    assert len(requests) == 1
    assert page.locator("#job-notice").is_hidden()


def test_unsupported_files_are_listed_and_count_is_checked(page: Any, fake_api: FakeApi) -> None:
    """TIFF (and other) files are named as skipped; too few photos are refused before sending."""
    uploads_before = len(fake_api.uploads)
    page.set_input_files("#photos", [
        _png("a.png"), _png("b.png"),
        {"name": "scan.tif", "mimeType": "image/tiff", "buffer": b"II*\x00" + bytes(60)},
        {"name": "notes.txt", "mimeType": "text/plain", "buffer": b"hello"}])
    assert page.locator("#thumbs li").count() == 2
    skipped = page.locator("#skipped")
    assert skipped.is_visible()
    text = skipped.inner_text()
    assert "scan.tif" in text and "notes.txt" in text
    assert "JPEG, PNG, WebP, HEIC" in text
    assert "add 1 more" in page.inner_text("#photo-count")
    page.click("#submit")
    error = page.locator("#form-error")
    error.wait_for(state="visible")
    assert "add 1 more" in error.inner_text() and "3 to 10" in error.inner_text()
    assert len(fake_api.uploads) == uploads_before  # nothing was sent
    page.set_input_files("#photos", [_png("c.png")])
    assert skipped.is_hidden()
    assert page.inner_text("#photo-count") == "3 photos chosen"


def test_heic_photos_are_added_with_a_placeholder_thumbnail(page: Any) -> None:
    """Chromium cannot show HEIC: the photo is kept, its thumbnail is its name."""
    page.set_input_files("#photos", [
        {"name": "IMG_0001.HEIC", "mimeType": "image/heic", "buffer": b"\x00" * 64},
        {"name": "IMG_0002.heic", "mimeType": "", "buffer": b"\x00" * 64}])
    assert page.locator("#thumbs li").count() == 2 and page.locator("#skipped").is_hidden()
    page.wait_for_function("document.querySelectorAll('#thumbs li .placeholder').length === 2")
    assert page.locator("#thumbs li .placeholder").all_inner_texts() == ["IMG_0001.HEIC",
                                                                         "IMG_0002.heic"]
    assert page.locator("#thumbs li img").count() == 0  # no broken image left


def test_upload_progress_reaches_100(page: Any, fake_api: FakeApi) -> None:
    """The upload goes through XMLHttpRequest with the same fields and header, with progress."""
    page.click("details summary")
    page.fill("#api-key", "secret-key")
    page.dispatch_event("#api-key", "change")
    page.evaluate("""() => {
        window.uploadTexts = [];
        new MutationObserver(() => window.uploadTexts.push(
            document.getElementById('upload-text').textContent))
          .observe(document.getElementById('upload-text'), {childList: true, characterData: true,
                                                           subtree: true});
    }""")
    _submit_three(page, size=3 * 2**20)  # ~9 MiB in all
    page.wait_for_function("() => document.getElementById('upload-bar').value === 100")
    assert page.locator("#upload-progress").is_visible()
    assert "100%" in page.inner_text("#upload-text")
    texts = page.evaluate("() => window.uploadTexts")
    assert texts and texts[0].startswith("Uploading") and texts[-1] == "Uploaded 100%"
    page.wait_for_selector("#result", state="visible")
    upload = fake_api.uploads[-1]
    assert upload["authorization"] == "Bearer secret-key"
    assert upload["content_type"].startswith("multipart/form-data; boundary=")
    assert upload["images"] == ["photo0.png", "photo1.png", "photo2.png"]
    assert upload["config"] == {"preset": "test"}
    assert upload["bytes"] > 9 * 2**20


def test_upload_error_body_is_shown(page: Any, fake_api: FakeApi) -> None:
    """A JSON error answer to the upload is shown as before (photo: message (hint))."""
    page.set_input_files("#photos", [_png("a.png"), _png("bad.png"), _png("c.png")])
    page.click("#submit")
    error = page.locator("#form-error")
    error.wait_for(state="visible")
    assert error.inner_text() == "bad.png: not an image (the file is truncated or damaged)"
    assert page.locator("#upload-progress").is_hidden()
    assert page.locator("#status").is_hidden()
    assert page.locator("#submit").is_enabled()


def _follow_scripted(page: Any, fake_api: FakeApi, **fields: Any) -> str:
    """Open the page on a job whose every poll answers `_status(id, **fields)`."""
    job_id = str(uuid.uuid4())
    with fake_api.lock:
        fake_api.scripted[job_id] = fields
    page.goto(f"{fake_api.url}/?job={job_id}")
    page.wait_for_selector("#status", state="visible")
    return job_id


@pytest.mark.parametrize(("fields", "expected"), [
    ({"queue_position": 2, "eta_s": 180.0}, "queued \u00b7 2 jobs ahead \u00b7 about 3 min left"),
    ({"queue_position": 1, "eta_s": 40.0}, "queued \u00b7 1 job ahead \u00b7 about 40 s left"),
    ({"queue_position": 0, "eta_s": 95.0}, "queued \u00b7 starts next \u00b7 about 2 min left"),
    ({"queue_position": 3, "eta_s": None}, "queued \u00b7 3 jobs ahead"),
    ({"queue_position": 12, "eta_s": 9000.0},
     "queued \u00b7 12 jobs ahead \u00b7 about 2.5 h left"),
    ({"queue_position": None, "eta_s": None}, "queued"),
    ({"state": "running", "stage": "phase2", "progress": 0.4, "eta_s": 30.0, "started_at": 1.0},
     "running \u00b7 phase2 \u00b7 40% \u00b7 about 30 s left"),
])
def test_queue_position_and_eta(page: Any, fake_api: FakeApi, fields: dict[str, Any],
                                expected: str) -> None:
    """A queued job shows the jobs ahead and the time until done; a running one is as before."""
    job_id = _follow_scripted(page, fake_api, **fields)
    page.wait_for_function("(text) => document.getElementById('status-text').textContent === text",
                           arg=expected)
    assert page.locator("#cancel").is_visible()  # still being followed
    assert page.locator("#job-error").is_hidden()
    polls = fake_api.polls[job_id]
    page.wait_for_timeout(1500)
    assert fake_api.polls[job_id] > polls  # queued and running jobs keep being polled


def test_failed_job_shows_error_detail(page: Any, fake_api: FakeApi) -> None:
    """error_detail: the photo name in bold, the message, and the hint on a line of its own."""
    job_id = _follow_scripted(
        page, fake_api, state="failed", stage="masks", progress=0.05,
        error="IMG_1.jpg: no object found in the photo (upload a mask)",
        error_detail={"code": "empty_mask", "message": "no object found in the photo",
                      "photo": "IMG_1.jpg", "hint": "upload a mask"})
    error = page.locator("#job-error")
    error.wait_for(state="visible")
    assert page.locator("#job-error strong").inner_text() == "IMG_1.jpg"
    assert page.evaluate("() => getComputedStyle(document.querySelector('#job-error strong'))"
                         ".fontWeight") == "700"
    lines = [line.strip() for line in error.inner_text().splitlines() if line.strip()]
    assert lines == ["IMG_1.jpg: no object found in the photo", "What to do: upload a mask"]
    assert "failed" in page.inner_text("#status-text")
    assert page.locator("#cancel").is_hidden()
    polls = fake_api.polls[job_id]
    page.wait_for_timeout(1500)
    assert fake_api.polls[job_id] == polls  # a failed job is not polled any more


def test_failed_job_detail_is_text_not_markup(page: Any, fake_api: FakeApi) -> None:
    """Server strings (the photo name is the user's file name) are shown as text, never parsed."""
    photo = "<img src=x onerror=alert(1)>.jpg"
    _follow_scripted(page, fake_api, state="failed", error="x",
                     error_detail={"code": "unreadable_image", "photo": photo,
                                   "message": "<b>not</b> an image"})
    error = page.locator("#job-error")
    error.wait_for(state="visible")
    assert page.locator("#job-error img, #job-error b").count() == 0
    assert page.locator("#job-error strong").inner_text() == photo
    assert error.inner_text().strip() == f"{photo}: <b>not</b> an image"
    assert "What to do" not in error.inner_text()  # no hint, no line for it


def test_failed_job_without_detail_shows_error(page: Any, fake_api: FakeApi) -> None:
    """An older server (no error_detail) still gets its `error` string shown as before."""
    _follow_scripted(page, fake_api, state="failed", error="phase1: out of GPU memory")
    error = page.locator("#job-error")
    error.wait_for(state="visible")
    assert error.inner_text() == "phase1: out of GPU memory"
    assert page.locator("#job-error strong").count() == 0


def test_presets_without_times_say_not_measured_yet(page: Any) -> None:
    # A server that gives no preset_times (an older one): every preset reads "not measured yet".
    texts = page.eval_on_selector_all("#preset option", "(os) => os.map((o) => o.textContent)")
    assert texts == ["fast \u2013 not measured yet", "test \u2013 not measured yet"]
    assert page.input_value("#preset") == "test"
    assert page.inner_text("#preset-time") == "test: not measured yet on this server."
