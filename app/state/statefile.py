"""Each job's ``state.json``: its record, kept where the job's data lives so it survives Redis.

On the data root the file sits in the job folder; with object storage it is an object beside
the job's other files, so an API on another machine re-seeds a job Redis lost just the same.
Where that is, is the job folder owner's business (``cadnerf_core.jobfolder`` storage).
"""

from __future__ import annotations

import logging

import redis
from pydantic import ValidationError

from app.core import JobStorage, open_storage
from app.settings import Settings
from app.state import keys
from app.state.records import JobRecord, is_job_id

log = logging.getLogger(__name__)

STATE_FILE = "state.json"


class StateFiles:
    """Reads and writes the ``state.json`` of jobs.

    Args:
        client: the Redis client (a deleted job's tombstone keeps its file from coming back).
        storage: where the job data lives.
    """

    def __init__(self, client: redis.Redis, storage: JobStorage) -> None:
        self._r = client
        self.storage = storage

    def write(self, record: JobRecord) -> None:
        """Replace the job's file (skipped once the job is deleted: no writer brings it back).

        On the data root a deleted job's folder is gone, which the write respects; in the
        store the tombstone is asked, best effort (a leftover goes with the retention).
        """
        if self.storage.remote and self._tombstoned(record.id):
            return
        try:
            self.storage.write_bytes(record.id, STATE_FILE,
                                     record.model_dump_json(indent=1).encode())
        except OSError as exc:  # Redis keeps the state; the next mirror tries again
            log.warning("could not write the state of job %s: %s", record.id, exc)

    def read(self, job_id: str) -> JobRecord | None:
        """The saved record, None when absent or unreadable (the store away counts)."""
        if not is_job_id(job_id):
            return None
        try:
            data = self.storage.read_bytes(job_id, STATE_FILE)
            return None if data is None else JobRecord.model_validate_json(data)
        except (OSError, ValidationError, ValueError) as exc:
            log.debug("state of job %s unreadable: %s", job_id, exc)
            return None

    def exists(self, job_id: str) -> bool:
        """Whether the job has a saved record (a job Redis lost, not a deleted one)."""
        try:
            return self.storage.read_bytes(job_id, STATE_FILE) is not None
        except OSError:
            return False

    def _tombstoned(self, job_id: str) -> bool:
        try:
            return bool(self._r.exists(keys.deleted(job_id)))
        except redis.RedisError:  # the final state goes out while Redis is away
            return False


def open_checked_storage(settings: Settings) -> JobStorage:
    """The deployment's job storage (``CADNERF_STORAGE_URL``), checked once at start-up.

    Raises:
        StorageError: the store cannot be reached, the bucket is missing or access is denied;
            the message names the URL, the problem and what to do.
    """
    storage = open_storage(settings.storage_url, settings.data_root)
    storage.check()
    if storage.remote:
        log.info("job data in %s; %s holds scratch copies", storage.url, settings.data_root)
    return storage
