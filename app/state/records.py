"""What the service keeps about one job: its state, its error, and the record itself."""

from __future__ import annotations

import json
import re
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field

JOB_ID_RE = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-4[0-9a-f]{3}-[89ab][0-9a-f]{3}-[0-9a-f]{12}$")
ANON_OWNER = "-"


class JobState(StrEnum):
    """Where a job is in its life."""

    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def terminal(self) -> bool:
        """True once the job will not change any more."""
        return self in (JobState.succeeded, JobState.failed, JobState.cancelled)


class ErrorDetail(BaseModel):
    """What went wrong and what to do about it."""

    code: str
    message: str
    field: str | None = None
    photo: str | None = None
    hint: str | None = None
    limit: str | None = None  # a fair-use refusal: the limit reached (app.state.usage)
    maximum: float | None = None  # ... its value
    current: float | None = None  # ... the caller's use of it now
    retry_after_s: int | None = None  # ... seconds until it frees up (also `Retry-After`)


class JobRecord(BaseModel):
    """Everything the service keeps about one job (the Redis hash and state.json)."""

    id: str
    state: JobState = JobState.queued
    preset: str
    n_photos: int
    names: list[str] = Field(default_factory=list)
    owner: str = ANON_OWNER
    created_at: float
    started_at: float | None = None
    finished_at: float | None = None
    updated_at: float | None = None
    stage: str | None = None
    progress: float = 0.0
    eta_s: float | None = None
    error: str | None = None
    error_detail: ErrorDetail | None = None  # the failure, structured like an API error body
    webhook_url: str | None = None
    worker: str | None = None  # heartbeat name of the worker running it (while running)
    attempts: int = 0  # times it was queued again after its worker died
    work: dict[str, float] = Field(default_factory=dict)  # per stage, over the preset's (ETA)

    def to_hash(self) -> dict[str, str]:
        """Flat string mapping for HSET (None -> empty string, lists -> JSON)."""
        return encode(self.model_dump(mode="json"))

    @classmethod
    def from_hash(cls, raw: dict[str, str]) -> JobRecord:
        """Inverse of ``to_hash``."""
        data: dict[str, Any] = {k: (None if v == "" else v) for k, v in raw.items()}
        data["names"] = json.loads(data.get("names") or "[]")
        data["work"] = json.loads(data.get("work") or "{}")
        if data.get("error_detail") is not None:
            data["error_detail"] = json.loads(data["error_detail"])
        if data.get("progress") is None:
            data["progress"] = 0.0
        return cls.model_validate(data)


def encode(fields: dict[str, Any]) -> dict[str, str]:
    """Record fields as Redis hash values (None -> "", models and lists -> JSON)."""
    out = {}
    for key, value in fields.items():
        if value is None:
            out[key] = ""
        elif isinstance(value, BaseModel):
            out[key] = value.model_dump_json(exclude_none=True)
        elif isinstance(value, list | dict):
            out[key] = json.dumps(value)
        else:
            out[key] = str(value)
    return out


def is_job_id(value: str) -> bool:
    """True for a canonical lower-case uuid4 string (the only ids that map to folders)."""
    return bool(JOB_ID_RE.match(value))
