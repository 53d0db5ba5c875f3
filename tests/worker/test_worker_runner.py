"""The job runner's state transitions (the parts that run before the pipeline is called)."""

from __future__ import annotations

import json
import threading
import uuid
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from app.settings import load_settings
from app.state import JobState, JobStore, keys
from worker import runner


def _settings(store: JobStore, redis_url: str, secret: str = "", **overrides: object):
    return load_settings(redis_url=redis_url, data_root=store.data_root,
                         library_dir=Path("/nonexistent"), webhook_secret=secret, **overrides)


def test_unknown_and_finished_jobs_are_left_alone(store: JobStore, new_job, redis_url,
                                                 clean_redis) -> None:
    settings = _settings(store, redis_url)
    missing = str(uuid.uuid4())
    assert runner.execute(missing, settings, store)["state"] == "missing"
    assert clean_redis.exists(keys.job(missing)) == 0
    done = new_job(JobState.succeeded)
    assert runner.execute(done.id, settings, store)["state"] == "succeeded"
    unchanged = store.get(done.id)
    assert unchanged is not None and unchanged.started_at is None


def _cancel_with_local_webhook(store: JobStore, new_job, redis_url: str,
                               allow_private: bool) -> tuple[dict, list[dict]]:
    """Run a job cancelled before it starts whose webhook is a receiver on 127.0.0.1."""
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
        settings = _settings(store, redis_url, "k", webhook_allow_private=allow_private)
        outcome = runner.execute(record.id, settings, store)
    finally:
        server.shutdown()
    return {**outcome, "record_id": record.id}, calls


def test_a_job_cancelled_before_it_starts_ends_cancelled_and_calls_its_webhook(
        store: JobStore, new_job, redis_url) -> None:
    outcome, calls = _cancel_with_local_webhook(store, new_job, redis_url, allow_private=True)
    job_id = outcome.pop("record_id")
    assert outcome == {"id": job_id, "state": "cancelled", "error": None}
    saved = json.loads((store.job_dir(job_id) / "state.json").read_text())
    assert saved["state"] == "cancelled" and saved["finished_at"] is not None
    assert calls and calls[0]["id"] == job_id and calls[0]["state"] == "cancelled"


def test_a_webhook_to_a_private_address_is_not_called_by_default(store: JobStore, new_job,
                                                                 redis_url) -> None:
    outcome, calls = _cancel_with_local_webhook(store, new_job, redis_url, allow_private=False)
    assert outcome["state"] == "cancelled" and calls == []


def test_the_final_state_reaches_state_json_while_redis_is_away(store: JobStore, new_job,
                                                                redis_url) -> None:
    from app.embedded import free_port
    from app.state import connect

    record = new_job()
    down = JobStore(connect(f"redis://127.0.0.1:{free_port()}/0"), store.data_root)
    runner._finish(down, _settings(store, redis_url), record, JobState.failed, "boom",
                   redis_wait_s=1.0)
    saved = json.loads((store.job_dir(record.id) / "state.json").read_text())
    assert saved["state"] == "failed" and saved["error"] == "boom" and saved["finished_at"]


def test_a_final_state_lost_by_redis_is_reseeded_but_a_deleted_job_is_not(
        store: JobStore, new_job, redis_url, clean_redis) -> None:
    lost, deleted = new_job(), new_job()
    clean_redis.delete(keys.job(lost.id))  # Redis restarted empty
    store.delete(deleted)
    settings = _settings(store, redis_url)
    runner._finish(store, settings, lost, JobState.succeeded, None)
    runner._finish(store, settings, deleted, JobState.cancelled, None)
    assert clean_redis.hget(keys.job(lost.id), "state") == "succeeded"
    assert clean_redis.exists(keys.job(deleted.id)) == 0
    assert store.running_ids() == [] and store.queue_estimates([lost.id]) == {}


def test_an_unwritable_job_folder_gives_a_clear_error(tmp_path: Path) -> None:
    import errno

    folder = tmp_path / "job"
    exc = FileExistsError(errno.EEXIST, "File exists", str(folder / "checkpoints"))
    message = runner._storage_message(exc, folder)
    assert message.startswith("the job folder cannot be written: File exists")
    assert "`checkpoints`" in message and str(tmp_path) not in message
    full = OSError(errno.ENOSPC, "No space left on device", str(folder / "views" / "000.png"))
    assert "disk is full" in runner._storage_message(full, folder)
