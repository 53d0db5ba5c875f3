"""A small HTTP client of the service (used by `cadnerf demo` and the benchmarks)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx

_MEDIA = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png", ".webp": "image/webp",
          ".heic": "image/heic", ".heif": "image/heif", ".avif": "image/avif"}


class ServiceError(RuntimeError):
    """The service answered with an error."""


class JobClient:
    """Submit photos, follow a job, download its artifacts."""

    def __init__(self, base_url: str, api_key: str | None = None, timeout_s: float = 60.0) -> None:
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self.http = httpx.Client(base_url=base_url.rstrip("/"), headers=headers,
                                 timeout=timeout_s)

    def close(self) -> None:
        """Close the connection pool."""
        self.http.close()

    def _check(self, response: httpx.Response) -> Any:
        if response.is_error:
            raise ServiceError(f"{response.status_code}: {response.text[:500]}")
        return response.json()

    def submit(self, photos: Sequence[Path], masks: Sequence[Path] = (),
               config: dict[str, Any] | None = None) -> dict[str, Any]:
        """POST /v1/jobs with the photos in order; returns the new job's status."""
        with ExitStack() as stack:
            files = [("images", (p.name, stack.enter_context(p.open("rb")),
                                 _MEDIA.get(p.suffix.lower(), "application/octet-stream")))
                     for p in photos]
            files += [("masks", (m.name, stack.enter_context(m.open("rb")), "image/png"))
                      for m in masks]
            data = {"config": json.dumps(config)} if config else {}
            status: dict[str, Any] = self._check(self.http.post("/v1/jobs", files=files,
                                                                data=data))
        return status

    def status(self, job_id: str) -> dict[str, Any]:
        """GET /v1/jobs/{id}."""
        status: dict[str, Any] = self._check(self.http.get(f"/v1/jobs/{job_id}"))
        return status

    def result(self, job_id: str) -> dict[str, Any]:
        """GET /v1/jobs/{id}/result."""
        result: dict[str, Any] = self._check(self.http.get(f"/v1/jobs/{job_id}/result"))
        return result

    def follow(self, job_id: str, on_update: Callable[[dict[str, Any]], None] | None = None,
               poll_s: float = 1.0, timeout_s: float = 7200.0) -> dict[str, Any]:
        """Poll until the job reaches a final state (or ``timeout_s`` passes); returns it."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status(job_id)
            if on_update is not None:
                on_update(status)
            if status["state"] in ("succeeded", "failed", "cancelled"):
                return status
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still {status['state']} after {timeout_s} s")
            time.sleep(poll_s)

    def download(self, job_id: str, name: str, target: Path) -> Path:
        """Save artifact ``name`` of a job to ``target``."""
        target.parent.mkdir(parents=True, exist_ok=True)
        with self.http.stream("GET", f"/v1/jobs/{job_id}/artifacts/{name}") as response:
            if response.is_error:
                response.read()
                raise ServiceError(f"{response.status_code}: {response.text[:500]}")
            with target.open("wb") as handle:
                for chunk in response.iter_bytes():
                    handle.write(chunk)
        return target
