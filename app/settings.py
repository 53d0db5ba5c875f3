"""Deployment settings: the one ``Settings`` class, read from ``CADNERF_*`` environment variables.

A bad value stops start-up with a message that names the variable and what it accepts
(``load_settings`` turns pydantic's error into a ``SettingsError``).
"""

from __future__ import annotations

import hashlib
import ipaddress
from functools import cached_property
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "CADNERF_"
AUTO_PRESET = "auto"  # the default preset follows the workers' device (app.state.serving)
MB = 1024 * 1024


class SettingsError(ValueError):
    """A ``CADNERF_*`` variable holds a value the service cannot use."""


class Settings(BaseSettings):
    """Everything a deployment may change; each field is the variable ``CADNERF_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, extra="ignore", frozen=True)

    data_root: Path = Field(Path("data/jobs"), description="Folder holding one folder per job.")
    """The job folders; with ``storage_url`` set, only this machine's scratch copies."""
    storage_url: str = Field("", description="s3://BUCKET[/PREFIX]: job data in S3-compatible "
                             "object storage (endpoint and keys from AWS_ENDPOINT_URL, "
                             "AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_DEFAULT_REGION); "
                             "empty: the data root, shared by every process.")
    """Lets the API and workers run on machines that share no disk (``jobfolder`` storage)."""
    redis_url: str = Field("", description="redis:// URL; empty: `cadnerf serve` embeds Redis.")
    """Broker and job-state store."""
    library_dir: Path = Field(Path("library_data/build"), description="The built CAD library.")
    """Folder with the library's manifest.json (read by the API, loaded by workers)."""
    web_modules: Path = Field(Path("node_modules"), description="npm packages the web page "
                              "loads (its 3D viewer); absent: the page does without them.")
    """Installed by `make setup` (`npm ci`); served under /vendor/, never a CDN."""
    mask_model: Path | None = Field(None, description="An ONNX background-removal model for "
                                    "learned masks; unset: the built-in one.")
    """A deployment's own model (a job's config cannot name server files); must exist."""
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="Worker torch device.")
    """Where the worker trains: auto picks CUDA when available."""
    default_preset: str = Field(AUTO_PRESET, description="Preset used when a job names none; "
                                "auto: preview without a GPU, standard with one.")
    """One of cadnerf_core.config.PRESETS, or auto: the workers' device decides, so a CPU
    server offers the preset that finishes in minutes and a GPU server the quality one."""
    min_photos: int = Field(3, ge=1, le=100, description="Fewest photos per job.")
    """Retrieval needs a few views; the paper uses 3 or more."""
    max_photos: int = Field(10, ge=1, le=100, description="Most photos per job.")
    """Bounded so one job cannot occupy a worker for hours."""
    max_file_mb: float = Field(25.0, gt=0, le=1024, description="Largest single upload (MiB).")
    """Per-file limit, enforced while the upload streams in."""
    max_total_mb: float = Field(150.0, gt=0, le=8192, description="Largest request (MiB).")
    """Limit on all files of one job together."""
    upload_idle_timeout_s: float = Field(
        30.0, gt=0, le=3600, description="An upload that sends nothing for this long gets 408.")
    """Stalled clients lose their staging folder instead of holding it open indefinitely."""
    upload_deadline_s: float = Field(
        600.0, gt=0, le=86400, description="An upload not complete after this long gets 408.")
    """Bounds a client that trickles bytes just often enough to dodge the idle limit. The full
    default request limit (150 MiB) in 600 s needs about 256 KiB/s; a typical job (10 phone
    photos, 30-50 MB) needs 50-90 KB/s, well within a weak mobile uplink."""
    max_concurrent_uploads: int = Field(
        8, ge=1, le=1000, description="Uploads received at once; more get 503 + Retry-After.")
    """Bounds staging disk use (this times CADNERF_MAX_TOTAL_MB) and open files during uploads."""
    max_connections: int = Field(
        512, ge=0, le=100_000, description="uvicorn's limit_concurrency for `cadnerf serve`; "
        "0: no limit.")
    """Last resort beyond the upload cap: with this many connections or requests open, uvicorn
    answers new requests with a plain-text 503. Below the common 1024 open-file limit."""
    max_megapixels: float = Field(40.0, gt=0, le=500, description="Largest photo (megapixels).")
    """Read from the image header; guards against decompression bombs."""
    min_side_px: int = Field(64, ge=1, le=4096, description="Smallest photo side (pixels).")
    """Smaller photos carry too little silhouette to match."""
    api_keys: str = Field("", description="Comma-separated API keys; empty: open service.")
    """When set, every /v1 call needs `Authorization: Bearer <key>`."""
    retention_days: float = Field(7.0, gt=0, description="Days a job folder is kept.")
    """Older jobs are removed by the periodic cleanup."""
    cleanup_interval_s: float = Field(600.0, gt=0, description="Seconds between cleanups.")
    """How often the API sweeps old jobs and re-seeds Redis from state.json."""
    job_soft_time_limit_s: int = Field(3600, gt=0, description="Job fails after this long.")
    """Checked between steps, so the job stops cleanly with a clear error."""
    job_hard_time_limit_s: int = Field(3900, gt=0, description="Worker is killed after this.")
    """Last resort when a step hangs; must exceed the soft limit."""
    delete_wait_s: float = Field(5.0, ge=0, le=60, description="Seconds DELETE waits for a "
                                 "running job's worker to stop before answering.")
    """Only for ``worker_stopped`` in the answer: the job's folder is renamed away before the
    answer either way, and nothing re-creates it, so a late worker can no longer write."""
    max_queued_per_key: int = Field(
        20, ge=0, le=100_000, description="Queued jobs one key (or the anonymous owner) may "
        "have; more get 429. 0: no limit.")
    """A key's jobs take turns with other keys' (fair order), so this bounds the disk a key's
    waiting uploads hold rather than anyone's wait."""
    max_running_per_key: int = Field(
        0, ge=0, le=10_000, description="Jobs of one key running at once; its next job waits "
        "while it has this many. 0: no limit.")
    """Off by default: with fair order a busy key only gets workers no other key is waiting
    for; set it to keep some workers free for keys that arrive later."""
    max_uploads_per_minute: int = Field(
        30, ge=0, le=100_000, description="Submissions one key may start in a minute; more get "
        "429. 0: no limit.")
    """Counted when a submission passes the door (before its body is read)."""
    max_stored_mb_per_key: float = Field(
        5000.0, ge=0, description="MiB of job folders (uploads and results) one key may keep; "
        "a submission past it gets 429. 0: no limit.")
    """Frees up as the key deletes jobs or the retention removes them."""
    max_queue_length: int = Field(
        1000, ge=0, le=1_000_000, description="Queued jobs of all keys together; more get 503. "
        "0: no limit.")
    """The service degrades with a clear answer before the disk fills."""
    webhook_secret: str = Field("", description="HMAC-SHA256 key signing webhook bodies.")
    """Empty: webhooks are sent unsigned."""
    webhook_allow_private: bool = Field(
        False, description="Allow webhooks to private, loopback and link-local addresses; for "
        "tests and closed networks.")
    """Off: a webhook URL naming, or resolving to, a non-public address is refused (SSRF)."""

    @field_validator("default_preset")
    @classmethod
    def _known_preset(cls, value: str) -> str:
        from app.core import PRESETS

        if value != AUTO_PRESET and value not in PRESETS:
            raise ValueError(f"must be one of {', '.join([AUTO_PRESET, *sorted(PRESETS)])}")
        return value

    @field_validator("mask_model", mode="before")
    @classmethod
    def _existing_file(cls, value: object) -> object:
        if value is None or value == "":  # an empty variable means unset
            return None
        if not Path(str(value)).is_file():
            raise ValueError(f"{value} is not a file")
        return value

    @field_validator("storage_url")
    @classmethod
    def _storage_scheme(cls, value: str) -> str:
        from urllib.parse import urlparse

        if value and (urlparse(value).scheme != "s3" or not urlparse(value).netloc):
            raise ValueError("must be s3://BUCKET or s3://BUCKET/PREFIX (or be empty)")
        return value

    @field_validator("redis_url")
    @classmethod
    def _redis_scheme(cls, value: str) -> str:
        if value and not value.startswith(("redis://", "rediss://", "unix://")):
            raise ValueError("must start with redis://, rediss:// or unix:// (or be empty)")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> Settings:
        if self.min_photos > self.max_photos:
            raise ValueError("CADNERF_MIN_PHOTOS must not exceed CADNERF_MAX_PHOTOS")
        if self.max_file_mb > self.max_total_mb:
            raise ValueError("CADNERF_MAX_FILE_MB must not exceed CADNERF_MAX_TOTAL_MB")
        if self.job_hard_time_limit_s <= self.job_soft_time_limit_s:
            raise ValueError("CADNERF_JOB_HARD_TIME_LIMIT_S must exceed the soft limit")
        if self.upload_deadline_s <= self.upload_idle_timeout_s:
            raise ValueError("CADNERF_UPLOAD_DEADLINE_S must exceed CADNERF_UPLOAD_IDLE_TIMEOUT_S")
        if 0 < self.max_connections <= self.max_concurrent_uploads:
            raise ValueError("CADNERF_MAX_CONNECTIONS must exceed CADNERF_MAX_CONCURRENT_UPLOADS "
                             "(or be 0)")
        return self

    @property
    def max_file_bytes(self) -> int:
        """Per-file upload limit in bytes."""
        return int(self.max_file_mb * MB)

    @property
    def max_total_bytes(self) -> int:
        """Whole-request upload limit in bytes."""
        return int(self.max_total_mb * MB)

    @cached_property
    def api_key_hashes(self) -> frozenset[str]:
        """SHA-256 hex digests of the configured API keys (keys themselves are not kept around)."""
        keys = [k.strip() for k in self.api_keys.split(",") if k.strip()]
        return frozenset(hash_key(k) for k in keys)


def hash_key(key: str) -> str:
    """SHA-256 hex digest of an API key (what jobs record as their owner).

    Args:
        key: the bearer token.

    Returns:
        64 hex characters.
    """
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def non_public_reason(address: str) -> str | None:
    """Why an IP address is not a public unicast address, or None when it is.

    Shared by the API (IP literals in a submitted webhook URL) and the worker (every address a
    webhook host resolves to); it lives here because both import this light module.

    Args:
        address: an IPv4 or IPv6 address, e.g. "10.0.0.1", "::1", "fe80::1%eth0".

    Returns:
        A short description such as "a loopback address"; None for a public address.

    Raises:
        ValueError: ``address`` is not an IP address.
    """
    ip = ipaddress.ip_address(address)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped  # ::ffff:127.0.0.1 reaches 127.0.0.1
    checks = [(ip.is_loopback, "a loopback address"),
              (ip.is_link_local, "a link-local address (cloud metadata lives there)"),
              (ip.is_unspecified, "the unspecified address"),
              (ip.is_multicast, "a multicast address"),
              (ip.is_reserved, "a reserved address"),
              (ip.is_private, "a private address"),
              (not ip.is_global, "not a globally routable address")]  # e.g. 100.64.0.0/10
    return next((reason for failed, reason in checks if failed), None)


def load_settings(**overrides: object) -> Settings:
    """Read the settings from the environment, failing with a message naming the variable.

    Args:
        overrides: field values that win over the environment (tests, the CLI).

    Returns:
        The validated settings.

    Raises:
        SettingsError: a variable holds a value that cannot be used.
    """
    try:
        return Settings(**overrides)  # type: ignore[arg-type]
    except ValidationError as exc:
        raise SettingsError(describe_errors(exc)) from None


def describe_errors(exc: ValidationError) -> str:
    """One line per bad variable: ``CADNERF_NAME=value: what it accepts``.

    Args:
        exc: pydantic's validation error for ``Settings``.

    Returns:
        A message for a person.
    """
    lines = []
    for err in exc.errors():
        loc = [str(part) for part in err.get("loc", ())]
        name = f"{ENV_PREFIX}{loc[0].upper()}" if loc else "settings"
        message = str(err.get("msg", "invalid value")).removeprefix("Value error, ")
        value = err.get("input")
        shown = f"={value!r}" if loc and isinstance(value, str | int | float) else ""
        lines.append(f"{name}{shown}: {message}")
    return "invalid settings: " + "; ".join(lines)
