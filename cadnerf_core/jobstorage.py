"""Where a job's bytes live: this machine's data root, or S3-compatible object storage.

Part of the job folder's owner (``jobfolder`` re-exports it). Every process works on a local job
folder (``<data root>/<job id>``). With local storage that folder is the job's data and every
method below is a no-op or a plain disk read. With object storage (``s3://BUCKET/PREFIX``) the
store holds the job and a folder is a scratch copy: the API pushes an accepted upload, a worker
fetches a job's files, pushes what changed when a stage ends, and drops its copy afterwards;
the API fetches a finished job's results to serve them. Object keys are
``PREFIX/<job id>/<name in the job folder>``; nothing else spells them.

The endpoint and credentials come from boto3's standard sources (``AWS_ENDPOINT_URL``,
``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_DEFAULT_REGION``, or a profile), so
this module reads no environment itself. boto3 is imported only when object storage is used.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import urlparse

from cadnerf_core.jobnames import CHECKPOINTS, INPUTS

log = logging.getLogger(__name__)

SCHEME = "s3"
SYNCED = ".synced.json"
"""In a scratch folder: each file's size and mtime when it last matched the store (what a
push may skip)."""
SCRATCH = ".scratch"
"""Under a data root with object storage: the workers' copies of the jobs they run."""
RESULTS_FETCHED = ".results-fetched"
"""In a scratch folder: the finished job's results are all there (``fetch_results``)."""
SINGLE_PUT_BYTES = 64 * 1024 * 1024  # larger files go up in parts (boto's managed upload)
TRANSFER_THREADS = 8  # objects moved at once: a job is many small files, each one round trip
_NOT_RESULTS = (f"{INPUTS}/", f"{CHECKPOINTS}/")


class StorageError(OSError):
    """The job store cannot be used; the message names its URL, the problem and what to do."""


@dataclass(frozen=True)
class Transfer:
    """What one fetch or push moved."""

    files: int
    bytes: int
    seconds: float

    def __add__(self, other: Transfer) -> Transfer:
        return Transfer(self.files + other.files, self.bytes + other.bytes,
                        self.seconds + other.seconds)


NOTHING = Transfer(0, 0, 0.0)


def folder_bytes(folder: Path) -> int:
    """Bytes of the files under ``folder`` (0 when it is gone)."""
    total = 0
    for root, _dirs, files in os.walk(folder):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:  # removed while walking
                continue
    return total


class LocalStorage:
    """Job data in ``<data root>/<job id>`` on this machine: the folder is the job.

    Args:
        data_root: the folder holding one folder per job.
    """

    remote = False

    def __init__(self, data_root: Path) -> None:
        self.data_root = Path(data_root)
        self.url = str(self.data_root)

    def check(self) -> None:
        """Nothing to check: a broken data root is reported where it is written."""

    def push(self, job_id: str, folder: Path) -> Transfer:
        """Nothing to copy: the folder is the job's data."""
        return NOTHING

    def fetch(self, job_id: str, folder: Path) -> Transfer:
        """Nothing to copy: the folder is the job's data."""
        return NOTHING

    def fetch_results(self, job_id: str, folder: Path) -> Transfer:
        """Nothing to copy: the folder is the job's data."""
        return NOTHING

    def work_folder(self, job_id: str) -> Path:
        """Where a worker runs the job: its folder itself."""
        return self.data_root / job_id

    def release(self, folder: Path) -> None:
        """Keep the folder: it is the job's data, not a copy."""

    def remove(self, job_id: str) -> None:
        """Nothing beyond the folder, which its owner removes."""

    def job_ids(self) -> list[str]:
        """None beyond the folders under the data root."""
        return []

    def job_bytes(self, job_id: str) -> int:
        """Bytes the job's folder holds."""
        return folder_bytes(self.data_root / job_id)

    def newest(self, job_id: str) -> float | None:
        """When the job's folder last changed (None when it is gone)."""
        try:
            return (self.data_root / job_id).stat().st_mtime
        except OSError:
            return None

    def read_bytes(self, job_id: str, name: str) -> bytes | None:
        """A small file of the job, None when absent or unreadable."""
        try:
            return (self.data_root / job_id / name).read_bytes()
        except OSError:
            return None

    def write_bytes(self, job_id: str, name: str, data: bytes) -> None:
        """Replace a small file of the job atomically; skipped when the job folder is gone
        (a deleted job is never brought back)."""
        folder = self.data_root / job_id
        if not folder.is_dir():
            return
        tmp = folder / f".{name}.{os.getpid()}.tmp"
        try:
            tmp.write_bytes(data)
            os.replace(tmp, folder / name)
        except OSError as exc:  # the folder was deleted under us: the job is gone anyway
            log.debug("could not write %s of job %s: %s", name, job_id, exc)
            tmp.unlink(missing_ok=True)


class S3Storage:
    """Job data in an S3-compatible bucket; local folders are scratch copies.

    Args:
        url: ``s3://BUCKET`` or ``s3://BUCKET/PREFIX``.
        data_root: this machine's folder of scratch copies.
        client: a boto3 S3 client (default: one from boto3's standard configuration).
    """

    remote = True

    def __init__(self, url: str, data_root: Path | None = None, client: Any = None) -> None:
        self.data_root = Path(data_root) if data_root is not None else Path("data/jobs")
        parsed = urlparse(url)
        if parsed.scheme != SCHEME or not parsed.netloc:
            raise StorageError(f"the storage URL {url!r} is not s3://BUCKET[/PREFIX]; set "
                               "CADNERF_STORAGE_URL to one, or leave it empty for the local "
                               "data root")
        self.url = url
        self.bucket = parsed.netloc
        self.prefix = parsed.path.strip("/")
        self.client = client if client is not None else _default_client()

    # --- keys -----------------------------------------------------------------------------
    def _job_prefix(self, job_id: str) -> str:
        return f"{self.prefix}/{job_id}/" if self.prefix else f"{job_id}/"

    def _key(self, job_id: str, name: str) -> str:
        return self._job_prefix(job_id) + name

    def _objects(self, job_id: str) -> dict[str, dict[str, Any]]:
        """The job's objects: name in the job folder -> listing entry (Size, LastModified)."""
        start = self._job_prefix(job_id)
        return {entry["Key"][len(start):]: entry
                for page in self._pages(Prefix=start) for entry in page.get("Contents", [])}

    def _pages(self, **params: Any) -> list[dict[str, Any]]:
        """Every page of a listing of the bucket (``ListObjectsV2`` with ``params``)."""
        paginator = self.client.get_paginator("list_objects_v2")
        return self._calling(lambda: list(paginator.paginate(Bucket=self.bucket, **params)))()

    # --- checks and errors ----------------------------------------------------------------
    def check(self) -> None:
        """Raise ``StorageError`` unless the bucket answers (reachable, exists, allowed)."""
        self._calling(self.client.head_bucket)(Bucket=self.bucket)

    def _calling(self, call: Callable[..., Any]) -> Callable[..., Any]:
        """``call`` with boto's errors turned into a ``StorageError`` a person can act on."""
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            try:
                return call(*args, **kwargs)
            except Exception as exc:
                if not _is_boto_error(exc):  # a local disk's OSError, or a bug: as it is
                    raise
                raise StorageError(describe_failure(self.url, self.client, exc)) from exc
        return wrapped

    # --- moving files ---------------------------------------------------------------------
    def push(self, job_id: str, folder: Path) -> Transfer:
        """Upload the folder's files that changed since they last matched the store, and
        delete the objects of files removed since; returns what was uploaded."""
        start = time.perf_counter()
        synced = _read_synced(folder)
        current = {name: _signature(path) for name, path in _files(folder)}
        changed = [name for name, sig in current.items() if synced.get(name) != sig]
        gone = [name for name in synced if name not in current]
        self._parallel(lambda name: self._upload(job_id, name, folder / name), changed)
        if gone:
            self._delete_keys([self._key(job_id, name) for name in gone])
        _write_synced(folder, current)
        size = sum(current[name][0] for name in changed)
        return Transfer(len(changed), size, time.perf_counter() - start)

    def fetch(self, job_id: str, folder: Path) -> Transfer:
        """Download every file of the job into ``folder`` (created), e.g. a worker's scratch
        copy: inputs, config, results so far and checkpoints."""
        return self._fetch(job_id, folder, lambda name: True)

    def fetch_results(self, job_id: str, folder: Path) -> Transfer:
        """Download a finished job's results (no inputs, no checkpoints) into ``folder`` once;
        later calls find them there and move nothing."""
        if (folder / RESULTS_FETCHED).is_file():
            return NOTHING
        moved = self._fetch(job_id, folder, lambda name: not name.startswith(_NOT_RESULTS))
        (folder / RESULTS_FETCHED).touch()
        return moved

    def _fetch(self, job_id: str, folder: Path, wanted: Callable[[str], bool]) -> Transfer:
        start = time.perf_counter()
        objects = {name: entry for name, entry in self._objects(job_id).items()
                   if wanted(name) and _is_job_file(name)}
        folder.mkdir(parents=True, exist_ok=True)
        self._parallel(lambda name: self._download(job_id, name, folder / name), objects)
        synced = _read_synced(folder)
        synced.update({name: _signature(folder / name) for name in objects})
        _write_synced(folder, synced)
        size = sum(int(entry["Size"]) for entry in objects.values())
        return Transfer(len(objects), size, time.perf_counter() - start)

    def _upload(self, job_id: str, name: str, path: Path) -> None:
        """One file to its object: a single PUT when small, multipart when large."""
        key = self._key(job_id, name)
        if path.stat().st_size > SINGLE_PUT_BYTES:
            self._calling(self.client.upload_file)(str(path), self.bucket, key)
            return
        with path.open("rb") as body:
            self._calling(self.client.put_object)(Bucket=self.bucket, Key=key, Body=body)

    def _download(self, job_id: str, name: str, target: Path) -> None:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
        os.close(fd)
        try:
            answer = self._calling(self.client.get_object)(Bucket=self.bucket,
                                                           Key=self._key(job_id, name))
            with open(tmp, "wb") as out:
                self._calling(shutil.copyfileobj)(answer["Body"], out, 1 << 20)
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    def _parallel(self, move: Callable[[str], None], names: Iterable[str]) -> None:
        names = list(names)
        if len(names) <= 1:
            for name in names:
                move(name)
            return
        with ThreadPoolExecutor(min(TRANSFER_THREADS, len(names))) as pool:
            for future in [pool.submit(move, name) for name in names]:
                future.result()

    # --- the job as a whole ---------------------------------------------------------------
    def work_folder(self, job_id: str) -> Path:
        """Where a worker runs the job: ``<data root>/.scratch/<job id>``, apart from the
        folder an API on the same data root keeps of a finished job's results."""
        return self.data_root / SCRATCH / job_id

    def release(self, folder: Path) -> None:
        """Drop a scratch copy (the store keeps the job)."""
        shutil.rmtree(folder, ignore_errors=True)

    def remove(self, job_id: str) -> None:
        """Delete every object of the job."""
        keys = [self._key(job_id, name) for name in self._objects(job_id)]
        self._delete_keys(keys)

    def _delete_keys(self, keys: list[str]) -> None:
        for first in range(0, len(keys), 1000):  # DeleteObjects takes 1000 keys a call
            batch = [{"Key": key} for key in keys[first:first + 1000]]
            self._calling(self.client.delete_objects)(
                Bucket=self.bucket, Delete={"Objects": batch, "Quiet": True})

    def job_ids(self) -> list[str]:
        """Ids of the jobs with objects in the store."""
        start = f"{self.prefix}/" if self.prefix else ""
        return [common["Prefix"][len(start):].rstrip("/")
                for page in self._pages(Prefix=start, Delimiter="/")
                for common in page.get("CommonPrefixes", [])]

    def job_bytes(self, job_id: str) -> int:
        """Bytes the job's objects hold."""
        return sum(int(entry["Size"]) for entry in self._objects(job_id).values())

    def newest(self, job_id: str) -> float | None:
        """When the job's newest object was written (None without objects)."""
        times = [entry["LastModified"].timestamp() for entry in self._objects(job_id).values()]
        return max(times) if times else None

    def read_bytes(self, job_id: str, name: str) -> bytes | None:
        """A small object of the job, None when absent."""
        try:
            answer = self.client.get_object(Bucket=self.bucket, Key=self._key(job_id, name))
        except Exception as exc:
            if _error_code(exc) in ("NoSuchKey", "404"):
                return None
            raise StorageError(describe_failure(self.url, self.client, exc)) from exc
        data: bytes = answer["Body"].read()
        return data

    def write_bytes(self, job_id: str, name: str, data: bytes) -> None:
        """Replace a small object of the job (one PUT: readers see the old or the new)."""
        self._calling(self.client.put_object)(Bucket=self.bucket, Key=self._key(job_id, name),
                                              Body=data)


JobStorage = LocalStorage | S3Storage
"""Either kind of storage; callers never ask which."""


def open_storage(url: str | None, data_root: Path) -> JobStorage:
    """The storage a deployment names: ``s3://BUCKET[/PREFIX]``, or empty for the data root.

    Raises:
        StorageError: a URL that is not ``s3://BUCKET[/PREFIX]``.
    """
    if not url:
        return LocalStorage(data_root)
    return S3Storage(url, data_root)


def _default_client() -> Any:
    import boto3
    from botocore.config import Config

    config = Config(connect_timeout=5, read_timeout=60, retries={"max_attempts": 3},
                    max_pool_connections=TRANSFER_THREADS * 2)
    return boto3.session.Session().client("s3", config=config)


def _is_boto_error(exc: BaseException) -> bool:
    return type(exc).__module__.startswith(("botocore", "boto3", "s3transfer"))


def _error_code(exc: BaseException) -> str:
    response = getattr(exc, "response", None)
    if isinstance(response, dict):
        return str(response.get("Error", {}).get("Code", ""))
    return ""


def describe_failure(url: str, client: Any, exc: BaseException) -> str:
    """What went wrong with the store at ``url``, in words, with what to do."""
    endpoint = getattr(client.meta, "endpoint_url", "?") if client is not None else "?"
    code = _error_code(exc)
    where = f"the job store {url} (endpoint {endpoint})"
    if code in ("NoSuchBucket", "404"):
        return (f"{where}: the bucket does not exist; create it (e.g. `aws s3 mb "
                f"s3://{urlparse(url).netloc}`) or fix CADNERF_STORAGE_URL")
    if code in ("AccessDenied", "403", "InvalidAccessKeyId", "SignatureDoesNotMatch"):
        return (f"{where}: access denied ({code}); check AWS_ACCESS_KEY_ID and "
                "AWS_SECRET_ACCESS_KEY and the bucket's policy")
    if code:
        return f"{where} answered {code}: {exc}"
    return (f"{where} cannot be reached ({type(exc).__name__}: {exc}); check AWS_ENDPOINT_URL "
            "and that the store is running")


# --- the scratch folder's own records ------------------------------------------------------
def _files(folder: Path) -> list[tuple[str, Path]]:
    """(name in the job folder, path) of every file to keep in the store: no dotfiles
    (atomic writes' temporaries, this module's records)."""
    found = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for file in files:
            if not file.startswith("."):
                path = Path(root) / file
                found.append((path.relative_to(folder).as_posix(), path))
    return found


def _is_job_file(name: str) -> bool:
    parts = PurePosixPath(name).parts
    return bool(parts) and ".." not in parts and not any(p.startswith(".") for p in parts)


def _signature(path: Path) -> list[int]:
    stat = path.stat()
    return [stat.st_size, stat.st_mtime_ns]


def _read_synced(folder: Path) -> dict[str, list[int]]:
    try:
        data = json.loads((folder / SYNCED).read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _write_synced(folder: Path, synced: dict[str, list[int]]) -> None:
    tmp = folder / f"{SYNCED}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(synced))
    os.replace(tmp, folder / SYNCED)
