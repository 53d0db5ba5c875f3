"""Load driver: many concurrent clients submit small jobs and poll them against a live service.

Shared by tests/reliability/test_load.py (a small bounded run) and
benchmarks/bench_reliability.py (100 clients). Counts every answer, checks that no job is lost or
duplicated and that jobs start in submission order, and samples the API process's memory.
"""

from __future__ import annotations

import json
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import httpx

from tests.configs import tiny_request
from tests.reliability.support import photo_files, rss_mib

SMALL_JOB = tiny_request(phase1={"steps": 2}, phase2={"steps": 2}, phase3={"steps": 2},
                         export={"orbit_frames": 2, "novel_views": 0})


@dataclass
class ClientRecord:
    """What one client did."""

    index: int
    sent: float = 0.0  # monotonic time the upload started
    accepted: float = 0.0  # monotonic time the 202 arrived
    job_id: str | None = None
    requests: int = 0
    busy: int = 0  # 503 too_many_uploads answers, retried after their Retry-After
    errors: list[str] = field(default_factory=list)
    final_state: str | None = None


@dataclass
class LoadReport:
    """Figures of one load run."""

    clients: int
    duration_s: float
    requests: int
    busy_answers: int  # 503 too_many_uploads answers (retried; not errors)
    errors: list[str]
    submitted: int
    listed: int
    lost: list[str]
    duplicated: list[str]
    order_violations: list[tuple[str, str]]
    states: dict[str, int]
    rss_start_mib: float
    rss_peak_mib: float
    rss_end_mib: float
    submit_p50_s: float
    submit_max_s: float

    def as_dict(self) -> dict[str, Any]:
        """Plain figures (for the benchmark's markdown and the test's messages)."""
        return {k: v for k, v in self.__dict__.items() if k not in ("errors",)} | {
            "n_errors": len(self.errors), "first_errors": self.errors[:5]}


class RssSampler:
    """Samples a process's resident memory from a thread."""

    def __init__(self, pid: int, every_s: float = 0.1) -> None:
        self.pid = pid
        self.every_s = every_s
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.samples.append(rss_mib(self.pid))
            except OSError:
                return
            self._stop.wait(self.every_s)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join(5)


def _client(url: str, record: ClientRecord, deadline: float, stagger_s: float,
            headers: dict[str, str]) -> None:
    time.sleep(record.index * stagger_s)
    with httpx.Client(base_url=url, timeout=60, headers=headers) as http:
        while True:
            record.sent = time.monotonic()
            response = http.post("/v1/jobs", files=photo_files(3, size=(64, 64),
                                                               prefix=f"c{record.index}"),
                                 data={"config": json.dumps(SMALL_JOB)})
            record.accepted = time.monotonic()
            record.requests += 1
            # A well-behaved client: the service caps uploads received at once and says
            # when to come back (503 too_many_uploads with Retry-After).
            if (response.status_code != 503 or "Retry-After" not in response.headers
                    or time.monotonic() >= deadline):
                break
            record.busy += 1
            time.sleep(float(response.headers["Retry-After"]))
        if response.status_code != 202:
            record.errors.append(f"POST {response.status_code} {response.text[:120]}")
            return
        record.job_id = response.json()["id"]
        while time.monotonic() < deadline:
            poll = http.get(f"/v1/jobs/{record.job_id}")
            record.requests += 1
            if poll.status_code != 200:
                record.errors.append(f"GET {poll.status_code} {poll.text[:120]}")
            else:
                record.final_state = poll.json()["state"]
                if record.final_state in ("succeeded", "failed", "cancelled"):
                    return
            time.sleep(0.5)


def _list_all(url: str, headers: dict[str, str]) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = []
    offset = 0
    with httpx.Client(base_url=url, timeout=30, headers=headers) as http:
        while True:
            page = http.get("/v1/jobs", params={"limit": 100, "offset": offset}).json()
            items += page["items"]
            if not page.get("next"):
                return items
            offset += 100


def order_violations(records: list[ClientRecord],
                     started: dict[str, float | None]) -> list[tuple[str, str]]:
    """Pairs (a, b) where a's upload was accepted before b's was sent, yet b started first."""
    bad = []
    done = [r for r in records if r.job_id]
    for a in done:
        for b in done:
            if a.accepted >= b.sent or a.job_id == b.job_id:
                continue
            start_a, start_b = started.get(a.job_id or ""), started.get(b.job_id or "")
            if start_b is not None and (start_a is None or start_a > start_b):
                bad.append((a.job_id or "", b.job_id or ""))
    return bad


def run_load(url: str, api_pid: int, clients: int, duration_s: float,
             stagger_s: float = 0.01, headers: dict[str, str] | None = None) -> LoadReport:
    """Run ``clients`` concurrent submit-and-poll clients for at most ``duration_s``.

    Args:
        url: the service's base URL.
        api_pid: pid of the API process (its memory is sampled).
        clients: concurrent clients, one job each.
        duration_s: how long clients poll before giving up.
        stagger_s: delay between client starts (so some uploads strictly follow others).
        headers: extra headers (an API key).

    Returns:
        The figures.
    """
    headers = headers or {}
    records = [ClientRecord(i) for i in range(clients)]
    start = time.monotonic()
    deadline = start + duration_s
    with RssSampler(api_pid) as rss, ThreadPoolExecutor(clients) as pool:
        rss_start = rss_mib(api_pid)
        for future in [pool.submit(_client, url, r, deadline, stagger_s, headers)
                       for r in records]:
            future.result()
    elapsed = time.monotonic() - start
    listed = _list_all(url, headers)
    ids = [r.job_id for r in records if r.job_id]
    listed_ids = [item["id"] for item in listed]
    started = {item["id"]: item.get("started_at") for item in listed}
    states: dict[str, int] = {}
    for item in (i for i in listed if i["id"] in set(ids)):
        states[item["state"]] = states.get(item["state"], 0) + 1
    waits = sorted(r.accepted - r.sent for r in records if r.job_id)
    return LoadReport(
        clients=clients, duration_s=round(elapsed, 1),
        requests=sum(r.requests for r in records), busy_answers=sum(r.busy for r in records),
        errors=[e for r in records for e in r.errors], submitted=len(ids),
        listed=len(listed_ids), lost=sorted(set(ids) - set(listed_ids)),
        duplicated=sorted({i for i in listed_ids if listed_ids.count(i) > 1}),
        order_violations=order_violations(records, started), states=states,
        rss_start_mib=round(rss_start, 1), rss_peak_mib=round(max(rss.samples or [0.0]), 1),
        rss_end_mib=round(rss_mib(api_pid), 1),
        submit_p50_s=round(waits[len(waits) // 2], 3) if waits else 0.0,
        submit_max_s=round(waits[-1], 3) if waits else 0.0)
