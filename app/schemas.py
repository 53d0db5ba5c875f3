"""HTTP schemas, as a ladder: what a client sends, what every job shows, and more detail on top.

``JobCreate`` (the request's config) -> ``JobPublic`` (id, state, links) -> ``JobStatus``
(stage, progress, ETA, queue position, timestamps, error) ; ``JobResult`` (the outcome of a
succeeded job) is the core's (``cadnerf_core.jobresult``: the pipeline writes it, the API serves
it as written). ``JobState`` and ``ErrorDetail`` belong to the job state (``app.state``).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from app.core import ClientSettings, inline_refs
from app.core import JobResult as JobResult  # one schema, the core's: re-exported
from app.state import ErrorDetail, JobState


class JobCreate(BaseModel):
    """The `config` form field of `POST /v1/jobs` (JSON)."""

    model_config = ConfigDict(extra="forbid")

    preset: str | None = Field(None, description="Preset name; default: the server's.")
    overrides: ClientSettings = Field(
        default_factory=ClientSettings,
        description="The settings to change on top of the preset, nested by section (dotted "
                    "keys accepted); any other key is refused with a 422 naming it.")


def job_create_schema() -> dict[str, Any]:
    """``JobCreate``'s JSON Schema with nothing referenced: the `config` form field of the
    OpenAPI document, so `/docs` lists every setting a client may send."""
    return inline_refs(JobCreate.model_json_schema())


class JobLinks(BaseModel):
    """Where to look next."""

    self: str
    result: str
    web: str


class JobPublic(BaseModel):
    """What every job shows."""

    id: str
    state: JobState
    preset: str
    n_photos: int
    created_at: float = Field(description="Unix time the upload was accepted.")
    links: JobLinks


class JobStatus(JobPublic):
    """A job's progress."""

    stage: str | None = Field(None, description="masks, retrieval, phase1..3, render, export.")
    progress: float = Field(0.0, ge=0.0, le=1.0)
    eta_s: float | None = Field(
        None, description="Expected seconds left; for a queued job, until it is done (the wait "
        "included). Null while no estimate exists (no job of the preset measured yet).")
    queue_position: int | None = Field(
        None, ge=0, description="Queued jobs ahead of this one (0 = next); null unless queued.")
    started_at: float | None = None
    finished_at: float | None = None
    error: str | None = None
    error_detail: ErrorDetail | None = Field(
        None, description="Why the job failed, shaped like an error body's `error` (code, "
        "message, photo as uploaded, field, hint); null unless failed.")


class JobList(BaseModel):
    """A page of the caller's jobs, newest first."""

    items: list[JobStatus]
    total: int
    limit: int
    offset: int
    next: str | None = Field(None, description="URL of the next page, if any.")


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer."""

    error: ErrorDetail


class LibraryModel(BaseModel):
    """One model of the CAD library."""

    id: str
    category: str | None = None
    kind: str | None = None
    source: str | None = None
    licence: str | None = None
    n_triangles: int | None = None


class LibraryPublic(BaseModel):
    """The library the workers retrieve from."""

    models: list[LibraryModel]
    n_views: int | None = None


class DeleteResult(BaseModel):
    """Answer of `DELETE /v1/jobs/{id}`."""

    id: str
    deleted: bool
    previous_state: JobState
    worker_stopped: bool = Field(description="A running job's worker acknowledged the cancel "
                                 "within CADNERF_DELETE_WAIT_S. Either way the job's files are "
                                 "gone and its worker can no longer write them.")


class Readiness(BaseModel):
    """Answer of `/readyz`."""

    redis: bool
    workers: list[str]
    ready: bool


class PresetTimePublic(BaseModel):
    """A preset's expected time for a whole job on this server (`GET /v1/info`)."""

    seconds: float | None = Field(description="Expected seconds of a job (queue wait not "
                                  "included); null: not measured yet and no table entry.")
    measured: bool = Field(description="Measured by this server's workers; false: the ETA "
                           "table's default for the device.")


class LimitsPublic(BaseModel):
    """Fair-use limits per key, and the queue's cap (0 = no limit)."""

    queued_jobs: int = Field(description="Queued jobs a key may have (429 past it).")
    running_jobs: int = Field(description="Jobs of one key running at once (the next waits).")
    uploads_per_minute: int = Field(description="Submissions a key may start in a minute (429).")
    stored_bytes: int = Field(description="Bytes of job folders a key may keep (429 past it).")
    queue_length: int = Field(description="Queued jobs of all keys together (503 past it).")


class UsagePublic(BaseModel):
    """What the calling key uses now (`GET /v1/usage`)."""

    queued: int
    running: int
    done_today: int = Field(description="Jobs that reached a final state since 00:00 UTC.")
    bytes_stored: int = Field(description="Bytes of this key's job folders on disk.")
    uploads_last_minute: int
    limits: LimitsPublic


class ServiceInfo(BaseModel):
    """Presets and upload limits (`GET /v1/info`)."""

    presets: list[str]
    default_preset: str = Field(description="Used when a job names none: the deployment's "
                                "choice, else preview without a GPU and standard with one.")
    device: Literal["cpu", "cuda"] = Field("cpu", description="Where this server's workers "
                                           "train (what default_preset and preset_times are for).")
    preset_times: dict[str, PresetTimePublic] = Field(
        default_factory=dict, description="Each preset's expected job time on this server.")
    min_photos: int
    max_photos: int
    max_file_mb: float
    max_total_mb: float
    max_megapixels: float
    min_side_px: int
    limits: LimitsPublic | None = Field(None, description="Fair-use limits per key.")
