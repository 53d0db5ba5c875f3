"""Fixtures for the worker tests: a real Redis (see tests/redis_fixture.py) and a job store."""

from __future__ import annotations

import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


from app.state import JobRecord, JobState, JobStore, connect  # noqa: E402
from tests.configs import TINY_PRESET  # noqa: E402


@pytest.fixture()
def store(tmp_path: Path, redis_url: str, clean_redis: object) -> JobStore:
    """A job store on a fresh data root and a flushed Redis database."""
    (tmp_path / "jobs").mkdir()
    return JobStore(connect(redis_url), tmp_path / "jobs")


@pytest.fixture()
def new_job(store: JobStore) -> Callable[..., JobRecord]:
    """Create a job record and its (empty) folder."""
    def make(state: JobState = JobState.queued, preset: str = TINY_PRESET,
             webhook_url: str | None = None) -> JobRecord:
        record = JobRecord(id=str(uuid.uuid4()), preset=preset, n_photos=3, state=state,
                           names=["a.png", "b.png", "c.png"], created_at=time.time(),
                           webhook_url=webhook_url)
        store.job_dir(record.id).mkdir()
        store.create(record)
        return record
    return make
