"""A succeeded job's outcome, read from its folder through the core's ``JobFolder``: the
result its pipeline wrote, and its artifacts.

Only names on the folder's allow-list are ever served, and the resolved path must stay inside
the job folder (no ``..``, no symbolic links leading out).
"""

from __future__ import annotations

import logging
from pathlib import Path

from app.core import JobFolder, JobResult, StorageError, media_type
from app.errors import ApiError
from app.state import JobRecord, JobState, JobStore

log = logging.getLogger(__name__)

__all__ = ["artifact_path", "media_type", "read_result", "results_folder"]


def results_folder(store: JobStore, record: JobRecord) -> Path:
    """The folder on this machine holding a succeeded job's results.

    With object storage they are fetched from the store the first time (a succeeded job's
    files never change), so range requests, ETags and ``results.zip`` are served from a
    local file as on one machine.

    Raises:
        ApiError: 503 when the store cannot be reached.
    """
    folder = store.job_dir(record.id)
    if record.state != JobState.succeeded:
        return folder
    try:
        store.storage.fetch_results(record.id, folder)
    except StorageError as exc:
        log.error("job %s: results not fetched: %s", record.id, exc)
        raise ApiError(503, "storage_unavailable", "the job storage cannot be reached",
                       hint="try again later; the operator has to check the object store",
                       headers={"Retry-After": "30"}) from None
    return folder


def artifact_path(job_dir: Path, name: str) -> Path:
    """The file behind an artifact name, checked against the allow-list and the job folder.

    Args:
        job_dir: the job's folder.
        name: e.g. ``orbit.mp4`` or ``views/003.png``.

    Returns:
        An existing file inside ``job_dir``.

    Raises:
        ApiError: 404 for a name off the list, a missing file, or a path leaving the folder.
    """
    path = JobFolder(job_dir).artifact_path(name)
    if path is None:
        raise ApiError(404, "no_such_artifact", f"no artifact named {name[:80]!r}",
                       field="name", hint="see the result's `artifacts` for what exists")
    return path


def read_result(record: JobRecord, job_dir: Path) -> JobResult:
    """A succeeded job's result, as its pipeline wrote it (``result.json``).

    Raises:
        ApiError: 409 before the job succeeded; 404 when its result is missing or unreadable.
    """
    if record.state != JobState.succeeded:
        raise ApiError(409, "not_ready", f"the job is {record.state.value}; results exist once "
                       "it has succeeded", hint=f"poll /v1/jobs/{record.id} until state is "
                       "succeeded")
    try:
        result = JobFolder(job_dir).read_result()
    except (OSError, ValueError) as exc:
        log.error("job %s: result.json unreadable: %s", record.id, exc)
        result = None
    if result is None:
        raise ApiError(404, "no_result", "the job succeeded but its result cannot be read",
                       hint="submit the photos again; the operator can read the job's log.txt")
    return result
