"""The job runner's state transitions (the parts that run before the pipeline is called)."""

from __future__ import annotations

import json
import threading
import uuid
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from app.schemas import JobState
from app.settings import load_settings
from app.store import JobStore
from worker import runner


def _settings(store: JobStore, redis_url: str, secret: str = ""):
    return load_settings(redis_url=redis_url, data_root=store.data_root,
                         library_dir=Path("/nonexistent"), webhook_secret=secret)


def test_unknown_and_finished_jobs_are_left_alone(store: JobStore, new_job, redis_url) -> None:
    settings = _settings(store, redis_url)
    missing = str(uuid.uuid4())
    assert runner.execute(missing, settings, store)["state"] == "missing"
    assert store.r.exists(store.job_key(missing)) == 0
    done = new_job(JobState.succeeded)
    assert runner.execute(done.id, settings, store)["state"] == "succeeded"
    unchanged = store.get(done.id)
    assert unchanged is not None and unchanged.started_at is None


def test_a_job_cancelled_before_it_starts_ends_cancelled_and_calls_its_webhook(
        store: JobStore, new_job, redis_url) -> None:
    calls: list[dict] = []

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            calls.append(json.loads(self.rfile.read(int(self.headers["Content-Length"]))))
            self.send_response(200)
            self.end_headers()

        def log_message(self, *args: object) -> None:
            return

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        record = new_job(webhook_url=f"http://127.0.0.1:{server.server_address[1]}/")
        store.request_cancel(record.id)
        outcome = runner.execute(record.id, _settings(store, redis_url, "k"), store)
    finally:
        server.shutdown()
    assert outcome == {"id": record.id, "state": "cancelled", "error": None}
    saved = json.loads((store.job_dir(record.id) / "state.json").read_text())
    assert saved["state"] == "cancelled" and saved["finished_at"] is not None
    assert calls and calls[0]["id"] == record.id and calls[0]["state"] == "cancelled"
