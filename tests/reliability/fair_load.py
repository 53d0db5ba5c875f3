"""Fair-use load driver: several API keys submit many small jobs, one key after the other,
against a live service; counts the refusals the per-key limits give, checks that no job is lost
or duplicated, and measures how long each key's first job waits, in jobs started before it.

Used by benchmarks/bench_reliability.py. Submitting key after key is the worst case for a
first-come queue: the last key's first job would wait for every earlier key's jobs.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import httpx

from tests.reliability.load import SMALL_JOB
from tests.reliability.support import photo_files

FINAL = ("succeeded", "failed", "cancelled")


@dataclass
class FairReport:
    """Figures of one fair-use run."""

    keys: int
    per_key: int
    accepted: int = 0
    refused: dict[str, int] = field(default_factory=dict)  # 429/503 per limit (intended)
    errors: list[str] = field(default_factory=list)  # any other answer
    lost: list[str] = field(default_factory=list)
    duplicated: list[str] = field(default_factory=list)
    states: dict[str, int] = field(default_factory=dict)
    first_job_waits: list[int] = field(default_factory=list)  # per key, in jobs
    duration_s: float = 0.0

    @property
    def max_first_wait(self) -> int:
        """The largest wait of any key's first job (jobs started after it was accepted)."""
        return max(self.first_job_waits, default=0)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready figures."""
        return {**asdict(self), "max_first_wait": self.max_first_wait}


def _submit_all(http: httpx.Client, per_key: int, report: FairReport,
                accepted: list[tuple[str, float]]) -> None:
    """One key's submissions, as fast as they are answered; refusals are counted, not retried."""
    for index in range(per_key):
        response = http.post("/v1/jobs", files=photo_files(3, size=(64, 64), prefix=f"j{index}"),
                             data={"config": json.dumps(SMALL_JOB)})
        if response.status_code == 202:
            accepted.append((response.json()["id"], time.time()))
            continue
        error = response.json().get("error", {}) if response.headers.get(
            "content-type", "").startswith("application/json") else {}
        if response.status_code in (429, 503) and error.get("limit") and (
                "Retry-After" in response.headers):
            report.refused[error["limit"]] = report.refused.get(error["limit"], 0) + 1
        else:
            report.errors.append(f"POST {response.status_code} {response.text[:120]}")


def _listing(http: httpx.Client) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = []
    offset = 0
    while True:
        page = http.get("/v1/jobs", params={"limit": 100, "offset": offset}).json()
        items += page["items"]
        if not page.get("next"):
            return items
        offset += 100


def run_fair_load(url: str, api_keys: list[str], per_key: int, timeout_s: float) -> FairReport:
    """Each key submits ``per_key`` jobs in turn; then wait (up to ``timeout_s``) for all.

    Args:
        url: the service's base URL (one worker, the keys configured, limits on).
        api_keys: the keys, in the order they submit.
        per_key: submissions per key.
        timeout_s: how long to wait for the accepted jobs to reach a final state.
    """
    report = FairReport(keys=len(api_keys), per_key=per_key)
    start = time.monotonic()
    clients = [httpx.Client(base_url=url, timeout=60, headers={"Authorization": f"Bearer {k}"})
               for k in api_keys]
    accepted: list[list[tuple[str, float]]] = [[] for _ in api_keys]
    try:
        for http, mine in zip(clients, accepted, strict=True):
            _submit_all(http, per_key, report, mine)
        ids = [job_id for mine in accepted for job_id, _ in mine]
        report.accepted = len(ids)
        listed: list[dict[str, Any]] = []
        while time.monotonic() - start < timeout_s:
            listed = [item for http in clients for item in _listing(http)]
            if all(item["state"] in FINAL for item in listed):
                break
            time.sleep(1.0)
    finally:
        for http in clients:
            http.close()
    listed_ids = [item["id"] for item in listed]
    report.lost = sorted(set(ids) - set(listed_ids))
    report.duplicated = sorted({i for i in listed_ids if listed_ids.count(i) > 1})
    for item in listed:
        report.states[item["state"]] = report.states.get(item["state"], 0) + 1
    started = {item["id"]: item.get("started_at") for item in listed}
    report.first_job_waits = [_first_wait(mine, started) for mine in accepted if mine]
    report.duration_s = round(time.monotonic() - start, 1)
    return report


def _first_wait(mine: list[tuple[str, float]], started: dict[str, float | None]) -> int:
    """Jobs (of any key) started after the key's first job was accepted and before it started
    (all of them when it never started)."""
    first, accepted_at = mine[0]
    begin = started.get(first)
    return sum(1 for job_id, at in started.items()
               if job_id != first and at is not None and at > accepted_at
               and (begin is None or at < begin))
