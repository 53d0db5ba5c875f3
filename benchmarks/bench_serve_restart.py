"""`cadnerf serve` killed with -9 with jobs queued, then started again on the same data root.

Measures the seconds from the second start to ``/readyz`` answering 200 and to every job of the
first run done, and checks that no process of the first run is left (its worker dies with it;
its embedded Redis is saved and stopped by the second start). Jobs use the suite's tiny config;
the library is ``library_data/build`` when built, else a small one.

Run: ``.venv/bin/python -m benchmarks.bench_serve_restart [--jobs 3]``.
"""

from __future__ import annotations

import argparse
import json
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

import redis

from benchmarks.bench_reliability import _library
from tests.configs import tiny_request
from tests.e2e.test_serve import _alive, _embedded_redis_url, _ready_workers, _start_serve, _stop
from tests.reliability import jobs
from tests.reliability.support import render_photo_set

COMMAND = ".venv/bin/python -m benchmarks.bench_serve_restart"


def _pids(url: str, log: Path) -> tuple[int, int]:
    """(worker pid, embedded Redis pid) of a ready serve."""
    worker = int(_ready_workers(url, 180)[0].rsplit("-", 1)[1])
    server = redis.Redis.from_url(_embedded_redis_url(log)).info("server")
    return worker, int(server["process_id"])


def measure(n_jobs: int) -> dict[str, Any]:
    """Kill -9 a serve with ``n_jobs`` submitted, start another; the figures."""
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        folder = Path(tmp)
        library, photos = _library(folder), render_photo_set(folder / "photos")
        first, url, log = _start_serve(folder, library)
        try:
            worker, server = _pids(url, folder / "serve.log")
            ids = [jobs.submit(url, photos, tiny_request())["id"] for _ in range(n_jobs)]
            first.send_signal(signal.SIGKILL)
            first.wait(10)
        finally:
            log.close()
        time.sleep(2)
        left_after_kill = {"worker": _alive(worker), "redis": _alive(server)}
        (folder / "serve.log").rename(folder / "first.log")
        started = time.monotonic()
        second, url, log = _start_serve(folder, library)
        try:
            _ready_workers(url, 120)
            ready_s = time.monotonic() - started
            states = [jobs.wait_state(url, job_id, 600)[0]["state"] for job_id in ids]
            done_s = time.monotonic() - started
            text = (folder / "serve.log").read_text()
        finally:
            _stop(second, log, signal.SIGTERM)
        left_at_end = [pid for pid in (worker, server) if _alive(pid)]
    return {"jobs": n_jobs, "alive_right_after_kill": left_after_kill,
            "stale_redis_stopped_logged": "left its embedded Redis running" in text,
            "ready_s": round(ready_s, 1), "all_done_s": round(done_s, 1),
            "states": sorted(set(states)), "first_run_processes_left": left_at_end}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=3)
    result = measure(parser.parse_args().jobs)
    print(json.dumps(result))
    print(f"command: {COMMAND}")


def run(quick: bool) -> str:
    """``make bench``'s section: kill -9 of a serve holding three queued jobs, then a second
    serve on the same data root (the same in QUICK mode: the jobs are tiny)."""
    result = measure(3)
    left = result["first_run_processes_left"]
    return "\n".join([
        "## Restart after kill -9", "",
        "Command: `python -m benchmarks.bench_serve_restart --jobs 3`", "",
        f"- second serve ready after {result['ready_s']} s (goal: within 60 s); all "
        f"{result['jobs']} queued jobs ended {', '.join(result['states'])} after "
        f"{result['all_done_s']} s",
        f"- stale embedded Redis found and stopped (logged): "
        f"{'yes' if result['stale_redis_stopped_logged'] else 'no'}; processes of the first "
        f"run left at the end: {len(left)}", ""])


if __name__ == "__main__":
    main()
