"""Reliability benchmark: load (100 concurrent clients), the bad-input battery over HTTP,
time to recover from a killed worker, a restarted Redis and a killed worker mid-job, and fair
use (3 API keys x 50 submissions against one worker, the per-key limits on).

Runs a real uvicorn process and `cadnerf worker` processes on 127.0.0.1 against Redis
(``CADNERF_REDIS_URL`` or 127.0.0.1:6379, database 13, else an embedded server) and a redis-server
of its own for the restart. The library is ``library_data/build`` when built, else a tiny one.
Standalone: ``.venv/bin/python -m benchmarks.bench_reliability [--quick] [--fair-only]
[--fair-keys K --fair-jobs N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import redis

from tests.configs import tiny_request
from tests.reliability import jobs
from tests.reliability.cases import CASES
from tests.reliability.fair_load import FairReport, run_fair_load
from tests.reliability.load import run_load
from tests.reliability.support import (
    RELIABILITY_DB,
    ROOT,
    Live,
    free_port,
    photo_files,
    pipeline_ready,
    ready_workers,
    render_photo_set,
    start_live,
    start_redis,
    stop_live,
    wait_for,
)

log = logging.getLogger(__name__)
COMMAND = ".venv/bin/python -m benchmarks.bench_reliability"


def _redis_url(folder: Path) -> tuple[str, Any]:
    """Database 13 of the configured/local Redis, else of an embedded server (also returned)."""
    configured = os.environ.get("CADNERF_REDIS_URL") or "redis://127.0.0.1:6379"
    host = configured.split("://", 1)[-1].split("/", 1)[0]
    url = f"redis://{host}/{RELIABILITY_DB}"
    try:
        redis.Redis.from_url(url, socket_connect_timeout=0.5).ping()
        return url, None
    except (redis.RedisError, OSError, ValueError):
        from app.embedded import EmbeddedRedis

        server = EmbeddedRedis(folder / "redis" / "bench.rdb")
        server.start()
        return f"redis://127.0.0.1:{server.port}/{RELIABILITY_DB}", server


def _library(folder: Path) -> Path:
    built = ROOT / "library_data" / "build"
    if (built / "manifest.json").is_file():
        return built
    from cadnerf_core.library.format import LibrarySpec
    from library_data.build import build_library

    spec = LibrarySpec(n_azimuths=8, elevations=(0.0, 30.0), silhouette_size=32, grid_size=32)
    build_library(folder / "library", spec, jobs=1, model_ids=["chair_wood", "mug", "cuboid_slab"])
    return folder / "library"


def battery(url: str) -> dict[str, Any]:
    """Send every bad-input case; count answers by status class."""
    counts = {"sent": 0, "4xx": 0, "5xx": 0, "2xx": 0, "as_expected": 0}
    unexpected = []
    with httpx.Client(base_url=url, timeout=60) as http:
        for name in sorted(CASES):
            case = CASES[name]()
            response = http.post("/v1/jobs", files=case.files, data=case.texts)
            counts["sent"] += 1
            counts[f"{response.status_code // 100}xx"] = counts.get(
                f"{response.status_code // 100}xx", 0) + 1
            if response.status_code == case.status:
                counts["as_expected"] += 1
            else:
                unexpected.append(f"{name}: {response.status_code}")
        healthy = http.get("/healthz").status_code == 200
    return {**counts, "unexpected": unexpected, "healthy_after": healthy}


def worker_kill_recovery(live: Live) -> float:
    """Seconds from kill -9 of the idle worker to a new worker listed by /readyz."""
    assert live.worker is not None
    old = set(ready_workers(live.url))
    os.kill(live.worker.pid, signal.SIGKILL)
    live.worker.popen.wait(10)
    killed = time.monotonic()
    live.restart_worker()
    wait_for(lambda: bool(set(ready_workers(live.url)) - old), 180, 0.2)
    return round(time.monotonic() - killed, 1)


def mid_job_kill(live: Live, photos: list[Path]) -> dict[str, Any]:
    """Kill -9 the worker in phase two, start a new one; does the job finish, and how fast?"""
    job = jobs.submit(live.url, photos, tiny_request(phase2={"steps": 1500}))
    try:
        jobs.wait_state(live.url, job["id"], 300, until=("running",), stage="phase2",
                        every_s=0.05)
    except AssertionError as exc:
        return {"finished": False, "detail": f"never reached phase two: {str(exc)[:300]}"}
    assert live.worker is not None
    os.kill(live.worker.pid, signal.SIGKILL)
    live.worker.popen.wait(10)
    killed = time.monotonic()
    live.restart_worker()
    try:
        final, stages = jobs.wait_state(live.url, job["id"], 60)
    except AssertionError as exc:
        return {"finished": False, "after_s": round(time.monotonic() - killed, 1),
                "detail": str(exc)[:200]}
    return {"finished": final["state"] == "succeeded", "after_s":
            round(time.monotonic() - killed, 1), "stages_after_kill": stages}


def redis_restart_recovery(folder: Path) -> dict[str, Any]:
    """Own redis-server: kill it under a running API, count answers while down, restart it."""
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.settings import load_settings

    port = free_port()
    procs = [start_redis(folder / "own-redis", port)]
    settings = load_settings(redis_url=f"redis://127.0.0.1:{port}/0", data_root=folder / "rjobs",
                             library_dir=folder / "nolib", default_preset="preview")
    try:
        with TestClient(create_app(settings), raise_server_exceptions=False) as client:
            job_id = client.post("/v1/jobs", files=photo_files(3)).json()["id"]
            with contextlib.suppress(redis.RedisError):
                redis.Redis(port=port).shutdown(nosave=True)
            down = [client.get(f"/v1/jobs/{job_id}").status_code for _ in range(5)]
            procs.append(start_redis(folder / "own-redis", port))
            started = time.monotonic()
            wait_for(lambda: client.get(f"/v1/jobs/{job_id}").status_code == 200, 30, 0.05)
            back = client.get(f"/v1/jobs/{job_id}").json()
            return {"statuses_while_down": sorted(set(down)),
                    "recovered_s": round(time.monotonic() - started, 2),
                    "state_after": back.get("state")}
    finally:
        for proc in procs:
            proc.stop()


FAIR_LIMITS = {"max_queued_per_key": "20", "max_uploads_per_minute": "30"}  # the defaults


def fair_use(folder: Path, url: str, library: Path, keys: int, per_key: int) -> FairReport:
    """Keys submit ``per_key`` jobs each, one key after the other, to an API and one worker
    with the default per-key limits; the figures of ``run_fair_load``."""
    names = [f"fair-key-{chr(ord('a') + i)}" for i in range(keys)]
    redis.Redis.from_url(url).flushdb()
    live = start_live(folder / "fair", url, library, True, api_keys=",".join(names),
                      **FAIR_LIMITS)
    try:
        return run_fair_load(live.url, names, per_key, timeout_s=900.0)
    finally:
        stop_live(live)


def _fair_lines(fair: FairReport | None) -> list[str]:
    if fair is None:
        return []
    refused = ", ".join(f"{n} {limit}" for limit, n in sorted(fair.refused.items())) or "none"
    return [
        f"| fair use: keys x submissions / accepted / refused (429, intended) | {fair.keys} x "
        f"{fair.per_key} / {fair.accepted} / {refused} |",
        f"| fair use: other errors / lost / duplicated | {len(fair.errors)} / {len(fair.lost)}"
        f" / {len(fair.duplicated)} |",
        f"| fair use: largest wait of a key's first job (per key) | {fair.max_first_wait} jobs"
        f" ({', '.join(map(str, fair.first_job_waits))}) |",
        f"| fair use: job states at the end ({fair.duration_s} s) | {fair.states} |",
    ]


def _mid_job_text(mid: Any) -> str:
    if not isinstance(mid, dict):
        return str(mid)
    if mid.get("finished"):
        return f"yes, {mid['after_s']} s after the kill (stages {mid.get('stages_after_kill')})"
    after = f" within {mid['after_s']} s" if "after_s" in mid else ""
    return f"no{after}: {str(mid.get('detail', ''))[:90]}"


def _section(figures: dict[str, Any], quick: bool) -> str:
    lines = ["## Reliability", "",
             f"Command: `{COMMAND}{' --quick' if quick else ''}` (uvicorn + `cadnerf worker` "
             "subprocesses, real Redis, 127.0.0.1 only).", "",
             "| check | figure |", "| --- | --- |"]
    if "load" in figures:
        lines += _main_lines(figures)
    return "\n".join(lines + _fair_lines(figures.get("fair"))) + "\n"


def _main_lines(figures: dict[str, Any]) -> list[str]:
    load = figures["load"]
    bat = figures["battery"]
    return [
        f"| load: clients / requests / error answers | {load['clients']} / {load['requests']} / "
        f"{load['n_errors']} |",
        f"| load: busy answers (503 `too_many_uploads`, retried after `Retry-After`) | "
        f"{load['busy_answers']} |",
        f"| load: jobs submitted / lost / duplicated | {load['submitted']} / "
        f"{len(load['lost'])} / {len(load['duplicated'])} |",
        f"| load: start-order violations | {len(load['order_violations'])} |",
        f"| load: job states at the end ({load['duration_s']} s) | {load['states']} |",
        f"| load: upload accepted in (median / max) | {load['submit_p50_s']} s / "
        f"{load['submit_max_s']} s |",
        f"| load: API RSS start / peak / end | {load['rss_start_mib']} / {load['rss_peak_mib']}"
        f" / {load['rss_end_mib']} MiB |",
        f"| bad inputs: sent / 4xx / 5xx / as expected | {bat['sent']} / {bat['4xx']} / "
        f"{bat['5xx']} / {bat['as_expected']} |",
        f"| bad inputs: unexpected answers | {', '.join(bat['unexpected']) or 'none'} |",
        f"| killed idle worker -> new worker ready | {figures['worker_kill_s']} s |",
        f"| Redis killed: answers while down | {figures['redis']['statuses_while_down']} |",
        f"| Redis restarted empty -> job back from state.json | "
        f"{figures['redis']['recovered_s']} s (state {figures['redis']['state_after']}) |",
        f"| worker killed in phase two -> job finished | {_mid_job_text(figures['mid_job'])} |",
    ]


def run(quick: bool, fair_only: bool = False, fair: tuple[int, int] | None = None) -> str:
    """Run the reliability benchmark; returns its markdown section.

    Args:
        quick: shorter runs (30 clients for 40 s; 3 keys x 10 submissions).
        fair_only: run only the fair-use part.
        fair: (keys, submissions per key) of the fair-use run instead of the default.
    """
    clients, duration = (30, 40.0) if quick else (100, 150.0)
    keys, per_key = fair or ((3, 10) if quick else (3, 50))
    figures: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="cadnerf-rel-") as tmp:
        folder = Path(tmp)
        url, embedded = _redis_url(folder)
        try:
            library = _library(folder)
            if not fair_only:
                figures.update(_main_figures(folder, url, library, clients, duration))
            figures["fair"] = fair_use(folder, url, library, keys, per_key)
        finally:
            redis.Redis.from_url(url).flushdb()
            if embedded is not None:
                embedded.stop()
    log.info("reliability figures: %s", json.dumps(
        {k: v.as_dict() if isinstance(v, FairReport) else v for k, v in figures.items()},
        default=str)[:2000])
    return _section(figures, quick)


def _main_figures(folder: Path, url: str, library: Path, clients: int,
                  duration: float) -> dict[str, Any]:
    """Load, the bad-input battery and the recoveries, on one live service."""
    redis.Redis.from_url(url).flushdb()
    live = start_live(folder / "service", url, library)
    try:
        figures: dict[str, Any] = {}
        figures["load"] = run_load(live.url, live.api.pid, clients, duration,
                                   stagger_s=0.02).as_dict()
        figures["battery"] = battery(live.url)
        figures["worker_kill_s"] = worker_kill_recovery(live)
        figures["redis"] = redis_restart_recovery(folder)
        figures["mid_job"] = (mid_job_kill(live, render_photo_set(folder / "photos"))
                              if pipeline_ready() else "not run: no pipeline")
        return figures
    finally:
        stop_live(live)


def main() -> None:
    """Print the section (standalone use)."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="30 clients for 40 s")
    parser.add_argument("--fair-only", action="store_true", help="only the fair-use run")
    parser.add_argument("--fair-keys", type=int, default=0, help="keys of the fair-use run")
    parser.add_argument("--fair-jobs", type=int, default=0, help="submissions per key")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    fair = (args.fair_keys, args.fair_jobs) if args.fair_keys and args.fair_jobs else None
    sys.stdout.write(run(args.quick, args.fair_only, fair))


if __name__ == "__main__":
    main()
