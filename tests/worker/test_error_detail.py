"""A failed job's structured error: the photo as uploaded, the hint, the API's error shape."""

from __future__ import annotations

import json
import sys
import time
import types
import uuid
from pathlib import Path

import pytest

from app import jobs
from app.settings import load_settings
from app.state import ErrorDetail, JobRecord, JobState, JobStore, keys
from tests.configs import TINY_PRESET
from worker import runner

HINT = "export or upload it again"


def _failing_job(store: JobStore, monkeypatch: pytest.MonkeyPatch, redis_url: str,
                 exc: Exception) -> JobRecord:
    """Run a job whose pipeline raises ``exc``; returns its final record."""
    record = JobRecord(id=str(uuid.uuid4()), preset=TINY_PRESET, n_photos=3,
                       names=["IMG_0001.JPG", "foo.jpg", "side view.png"], created_at=time.time())
    store.job_dir(record.id).mkdir()
    store.create(record)

    def run_job(job_dir: Path, library: object, progress: object, device: str,
                mask_model: Path | None = None) -> None:
        raise exc

    fake = types.ModuleType("cadnerf_core.pipeline")
    fake.run_job = run_job  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "cadnerf_core.pipeline", fake)
    monkeypatch.setattr(runner, "get_library", lambda root: None)
    settings = load_settings(redis_url=redis_url, data_root=store.data_root,
                             library_dir=Path("/nonexistent"), device="cpu")
    outcome = runner.execute(record.id, settings, store)
    assert outcome["state"] == "failed"
    final = store.get(record.id)
    assert final is not None and final.state == JobState.failed
    return final


def test_an_input_error_names_the_uploaded_photo_and_its_hint(
        store: JobStore, monkeypatch: pytest.MonkeyPatch, redis_url: str, clean_redis) -> None:
    from cadnerf_core.errors import InputError

    exc = InputError("the photo is damaged or truncated", item="001_foo.jpg", hint=HINT)
    final = _failing_job(store, monkeypatch, redis_url, exc)
    expected = ErrorDetail(code="unusable_input", message="the photo is damaged or truncated",
                           photo="foo.jpg", hint=HINT)
    assert final.error_detail == expected
    assert final.error == f"foo.jpg: the photo is damaged or truncated ({HINT})"
    # The status shows it with the shape of an upload error body's "error".
    status = jobs.to_status(final).model_dump(mode="json")
    assert status["error_detail"] == expected.model_dump(mode="json")
    assert set(status["error_detail"]) == set(ErrorDetail.model_fields)
    assert status["error"] == final.error
    # It survives a Redis restart (state.json) like the rest of the record.
    saved = json.loads((store.job_dir(final.id) / "state.json").read_text())
    assert saved["error_detail"]["photo"] == "foo.jpg"
    clean_redis.delete(keys.job(final.id))
    reseeded = store.get(final.id)
    assert reseeded is not None and reseeded.error_detail == expected


def test_an_input_error_on_a_job_folder_path_shows_the_field_not_the_path(
        store: JobStore, monkeypatch: pytest.MonkeyPatch, redis_url: str) -> None:
    from cadnerf_core.errors import InputError

    exc = InputError("no photos in inputs/", item=str(store.data_root / "x" / "inputs"),
                     hint="add 3 to 10 ordered photos")
    final = _failing_job(store, monkeypatch, redis_url, exc)
    assert final.error_detail is not None and final.error_detail.photo is None
    assert final.error_detail.message == "no photos in inputs/"
    assert str(store.data_root) not in (final.error or "")
    masks = InputError("3 masks for 4 photos", item="masks", hint="one mask per photo")
    detail = _failing_job(store, monkeypatch, redis_url, masks).error_detail
    assert detail == ErrorDetail(code="unusable_input", message="3 masks for 4 photos",
                                 field="masks", hint="one mask per photo")


def test_an_input_error_inside_the_job_folder_maps_to_its_form_field(tmp_path: Path) -> None:
    record = JobRecord(id=str(uuid.uuid4()), preset=TINY_PRESET, n_photos=2,
                       names=["a.jpg", "b.jpg"], created_at=time.time())
    folder = tmp_path / record.id
    error, detail = runner.input_error(f"{folder / 'inputs'}: no photos", str(folder / "inputs"),
                                       None, record, folder)
    assert error == "inputs: no photos" and detail.field == "images" and detail.photo is None
    error, detail = runner.input_error("config.json: invalid configuration: x", "config.json",
                                       None, record, folder)
    assert detail.field == "config" and detail.message == "invalid configuration: x"
    # A stored name beyond the uploaded photos is not mapped to one.
    assert runner.uploaded_name("007_ghost.jpg", record) is None
    assert runner.uploaded_name(str(folder / "inputs" / "001_b.jpg"), record) == "b.jpg"


def test_other_failures_have_a_detail_too(store: JobStore, monkeypatch: pytest.MonkeyPatch,
                                          redis_url: str) -> None:
    final = _failing_job(store, monkeypatch, redis_url, RuntimeError("boom"))
    assert final.error_detail is not None and final.error_detail.code == "internal"
    assert final.error == "internal error (RuntimeError); see the worker log"


def test_a_new_run_clears_the_previous_detail(store: JobStore, new_job) -> None:
    record = new_job()
    store.update(record.id, error="old", error_detail=ErrorDetail(code="x", message="old"))
    assert store.update(record.id, allowed_from=(JobState.queued,), state=JobState.running,
                        error=None, error_detail=None)
    fresh = store.get(record.id)
    assert fresh is not None and fresh.error is None and fresh.error_detail is None
