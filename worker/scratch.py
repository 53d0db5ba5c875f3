"""A worker's scratch copy of one job: fetched before it runs, written back as it goes.

With object storage (``cadnerf_core.jobfolder`` storage) a worker shares no disk with the API:
the job's files are fetched into a scratch folder (``work_folder``), each stage's files (checkpoints
included) go back to the store when the stage ends, so another worker can resume the job if
this one dies, and everything goes back before the job is marked done. With the data root as
storage every step here moves nothing.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from cadnerf_core.jobfolder import JobStorage, Transfer
from cadnerf_core.progress import ProgressReporter

log = logging.getLogger(__name__)


class Scratch:
    """One job's local copy and its write-backs.

    Args:
        storage: where the job's data lives.
        job_id: the job.
        folder: its local folder (the storage's ``work_folder``).
        gone: True once the job was deleted or cancelled (nothing is written back then: a
            deleted job must not come back to the store).
    """

    def __init__(self, storage: JobStorage, job_id: str, folder: Path,
                 gone: Callable[[], bool]) -> None:
        self.storage = storage
        self.job_id = job_id
        self.folder = folder
        self.gone = gone
        self.fetched = Transfer(0, 0, 0.0)
        self.written = Transfer(0, 0, 0.0)

    def fetch(self) -> None:
        """Bring the job's files here (inputs, config, results so far, checkpoints)."""
        self.fetched = self.storage.fetch(self.job_id, self.folder)
        if self.storage.remote:
            log.info("job %s: fetched %d files (%d bytes) in %.2f s", self.job_id,
                     self.fetched.files, self.fetched.bytes, self.fetched.seconds)

    def reporting(self, reporter: ProgressReporter) -> ProgressReporter:
        """``reporter``, writing the last stage's files back whenever a new stage begins (a
        phase's checkpoint is saved before the next phase reports)."""
        last: list[str] = []

        def report(stage: str, done: int, total: int) -> None:
            if last and stage != last[0]:
                self.write_back(quiet=True)
            last[:] = [stage]
            reporter(stage, done, total)

        return report

    def write_back(self, quiet: bool = False) -> None:
        """Push what changed to the store (unless the job is gone).

        Args:
            quiet: log a failure and go on (a stage's write-back; the final one retries all).

        Raises:
            StorageError: the store cannot be written (not ``quiet``); OSError: the folder
                cannot be read.
        """
        if not self.storage.remote or self.gone():
            return
        try:
            moved = self.storage.push(self.job_id, self.folder)
        except OSError as exc:
            if not quiet:
                raise
            log.warning("job %s: write-back failed (%s); retried when the job ends",
                        self.job_id, exc)
            return
        self.written = self.written + moved
        log.info("job %s: wrote back %d files (%d bytes) in %.2f s", self.job_id, moved.files,
                 moved.bytes, moved.seconds)

    def release(self) -> None:
        """Drop the local copy (object storage only: the data root's folder is the job)."""
        self.storage.release(self.folder)
