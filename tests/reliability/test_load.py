"""A small bounded load run (the full one is benchmarks/bench_reliability.py): concurrent clients
submit small jobs and poll; no error answer, no job lost or duplicated, queue order kept, API
memory bounded."""

from __future__ import annotations

import pytest

from tests.reliability.load import run_load
from tests.reliability.support import Live

pytestmark = pytest.mark.slow

CLIENTS = 20
DURATION_S = 25.0


def test_concurrent_clients_lose_nothing_and_keep_order(service: Live) -> None:
    report = run_load(service.url, service.api.pid, CLIENTS, DURATION_S, stagger_s=0.05)
    figures = report.as_dict()
    assert report.errors == [], figures
    assert report.submitted == CLIENTS and report.listed >= CLIENTS, figures
    assert report.lost == [] and report.duplicated == [], figures
    assert report.order_violations == [], figures
    assert sum(report.states.values()) == CLIENTS
    assert set(report.states) <= {"queued", "running", "succeeded", "failed"}, figures
    # Uploads stream to disk: the API's memory does not grow with the number of uploads.
    assert report.rss_peak_mib < 400 and report.rss_end_mib - report.rss_start_mib < 80, figures
    assert service.api.popen.poll() is None and service.worker is not None
    assert service.worker.popen.poll() is None, service.logs()
