"""`cadnerf serve` killed with -9, then started again on the same data root: nothing of the
first run is left, the second is ready, and the jobs queued in the first one are done."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import psutil
import pytest
import redis

from tests.configs import tiny_request
from tests.e2e.test_serve import _alive, _embedded_redis_url, _ready_workers, _start_serve, _stop
from tests.reliability.jobs import submit, wait_state

pytestmark = pytest.mark.slow


def _gone(pids: list[int], timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` for every process in ``pids`` to end; True if they did."""
    deadline = time.monotonic() + timeout_s
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    return not any(_alive(p) for p in pids)


def _running(process: psutil.Process) -> bool:
    """True while that very process (not a later one given its pid) runs and is no zombie."""
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_a_serve_killed_with_9_restarts_clean(tmp_path: Path, tiny_library_dir: Path,
                                              photo_set: list[Path]) -> None:
    first, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        worker_pid = int(_ready_workers(url, 180)[0].rsplit("-", 1)[1])
        redis_url = _embedded_redis_url(tmp_path / "serve.log")
        redis_pid = int(redis.Redis.from_url(redis_url).info("server")["process_id"])
        jobs = [submit(url, photo_set, tiny_request(phase3={"steps": 40}))["id"]
                for _ in range(3)]
        # Every process below the first serve (its worker and whatever that started; the
        # embedded Redis daemonizes, so it is no descendant and is checked on its own).
        descendants = psutil.Process(first.pid).children(recursive=True)
        assert worker_pid in {p.pid for p in descendants}, descendants
        first.send_signal(signal.SIGKILL)
        first.wait(10)
    finally:
        if first.poll() is None:
            first.kill()
        log.close()
    # The worker dies with its parent; the embedded Redis is left for the next serve to stop.
    assert _gone([worker_pid], 60), "the worker outlived serve"
    os.replace(tmp_path / "serve.log", tmp_path / "first.log")
    second, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        new_worker = int(_ready_workers(url, 180)[0].rsplit("-", 1)[1])
        text = (tmp_path / "serve.log").read_text()
        assert f"left its embedded Redis running (pid {redis_pid}" in text, text[-3000:]
        assert _gone([redis_pid], 60), "the second serve did not stop the Redis left behind"
        assert new_worker != worker_pid
        for job_id in jobs:  # queued (or running) when serve died: done by the second one
            final, _ = wait_state(url, job_id, 240)
            assert final["state"] == "succeeded", (final, (tmp_path / "serve.log").read_text())
        new_redis = int(redis.Redis.from_url(_embedded_redis_url(tmp_path / "serve.log"))
                        .info("server")["process_id"])
    finally:
        _stop(second, log, signal.SIGTERM)
    assert _gone([new_worker, new_redis, worker_pid, redis_pid], 60), "a process outlived serve"
    left = [p for p in descendants if _running(p)]
    assert not left, [(p.pid, p.cmdline()) for p in left]
