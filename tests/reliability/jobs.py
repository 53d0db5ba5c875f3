"""Job helpers over HTTP for the reliability tests and benchmark (submit, poll, wait)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx

TERMINAL = ("succeeded", "failed", "cancelled")


def submit(url: str, photos: list[Path], config: dict[str, Any] | None = None,
           headers: dict[str, str] | None = None) -> dict[str, Any]:
    """POST the photos (in order) as a job; returns the 202 body."""
    with ExitStack() as stack:
        files = [("images", (p.name, stack.enter_context(p.open("rb")), "image/png"))
                 for p in photos]
        data = {"config": json.dumps(config)} if config is not None else {}
        response = httpx.post(f"{url}/v1/jobs", files=files, data=data, timeout=60,
                              headers=headers)
    assert response.status_code == 202, response.text
    body: dict[str, Any] = response.json()
    return body


def status(url: str, job_id: str) -> dict[str, Any]:
    """GET the job's status (raises on an error answer)."""
    response = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=10)
    response.raise_for_status()
    body: dict[str, Any] = response.json()
    return body


def wait_state(url: str, job_id: str, timeout_s: float,
               until: tuple[str, ...] = TERMINAL, stage: str | None = None,
               every_s: float = 0.1, context: Callable[[], str] | None = None,
               ) -> tuple[dict[str, Any], list[str]]:
    """Poll until the job's state is in ``until`` (and its stage is ``stage``, when given).

    ``context`` adds to the timeout's message (a live worker's log tail).

    Returns:
        The last status and the stages seen on the way, in order without repeats.

    Raises:
        AssertionError: on timeout (with the last status).
    """
    stages: list[str] = []
    last: dict[str, Any] = {}
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            last = status(url, job_id)
        except httpx.HTTPError:
            time.sleep(every_s)
            continue
        if last.get("stage") and (not stages or stages[-1] != last["stage"]):
            stages.append(last["stage"])
        if last["state"] in until and (stage is None or last.get("stage") == stage):
            return last, stages
        if stage is not None and last["state"] in TERMINAL:
            break
        time.sleep(every_s)
    more = f"\n{context()}" if context is not None else ""
    raise AssertionError(f"job {job_id} did not reach {until}/{stage}: {last}; stages {stages}"
                         f"{more}")


def artifact_names(url: str, job_id: str) -> set[str]:
    """The kinds of artifacts of a succeeded job (views/NNN.png counted as one kind)."""
    result = httpx.get(f"{url}/v1/jobs/{job_id}/result", timeout=10)
    result.raise_for_status()
    return {n.split("/")[0] if n.startswith("views/") else n for n in result.json()["artifacts"]}
