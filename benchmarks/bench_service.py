"""Service benchmark: polling latency under 100 concurrent clients, time to accept an upload.

Runs uvicorn (one process) on 127.0.0.1 against Redis (``CADNERF_REDIS_URL`` or 127.0.0.1:6379,
database 14, else an embedded server); no worker is needed, so the polled job stays queued.
Standalone: ``.venv/bin/python -m benchmarks.bench_service [--quick]``.
"""

from __future__ import annotations

import asyncio
import io
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import redis
from PIL import Image

from app.embedded import EmbeddedRedis, free_port

BENCH_DB = 14
POLLERS = 100


def _redis_url(folder: Path) -> tuple[str, EmbeddedRedis | None]:
    configured = os.environ.get("CADNERF_REDIS_URL") or "redis://127.0.0.1:6379"
    url = f"{configured.rsplit('/', 1)[0] if configured.count('/') > 2 else configured}/{BENCH_DB}"
    try:
        redis.Redis.from_url(url, socket_connect_timeout=0.5).ping()
        return url, None
    except (redis.RedisError, OSError):
        server = EmbeddedRedis(folder / "bench.rdb")
        server.start()
        return server.url.rsplit("/", 1)[0] + f"/{BENCH_DB}", server


def _photo(width: int, height: int, seed: int) -> bytes:
    """A JPEG with smooth shading and mild noise (compresses like a real photo)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = 128 + 60 * np.sin(x / 300.0 + seed) * np.cos(y / 200.0)
    noise = rng.normal(0, 6, (height, width, 1)).astype(np.float32)
    rgb = np.clip(base[..., None] + noise + np.array([0, 20, -20], np.float32), 0, 255)
    buffer = io.BytesIO()
    Image.fromarray(rgb.astype(np.uint8)).save(buffer, format="JPEG", quality=90)
    return buffer.getvalue()


def _start_server(url: str, folder: Path, port: int) -> subprocess.Popen[bytes]:
    env = {**os.environ, "CADNERF_REDIS_URL": url, "CADNERF_DATA_ROOT": str(folder / "jobs"),
           "CADNERF_DEFAULT_PRESET": "preview"}  # no worker runs: the job stays queued
    command = [sys.executable, "-m", "uvicorn", "--factory", "app.main:create_app",
               "--host", "127.0.0.1", "--port", str(port), "--log-level", "warning",
               "--timeout-keep-alive", "60"]  # pollers wait longer than the 5 s default
    server = subprocess.Popen(command, env=env)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                return server
        except httpx.HTTPError:
            time.sleep(0.2)
    server.kill()
    raise RuntimeError("uvicorn did not start")


async def _get(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
               request: bytes) -> int:
    """One keep-alive GET on an open connection; returns the status code."""
    writer.write(request)
    await writer.drain()
    head = await reader.readuntil(b"\r\n\r\n")
    length = 0
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            length = int(value)
    await reader.readexactly(length)
    return int(head.split(b" ", 2)[1])


async def _poll(port: int, job_id: str, rounds: int, pollers: int) -> list[float]:
    """``pollers`` clients, each on its own keep-alive connection, polling the job.

    A minimal asyncio HTTP/1.1 client: httpx's pool costs more CPU than the server under test
    when both share two cores.
    """
    request = (f"GET /v1/jobs/{job_id} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").encode()

    async def poller() -> list[float]:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        times = []
        try:
            await _get(reader, writer, request)  # connection set up and warm
            for _ in range(rounds):
                start = time.perf_counter()
                status = await _get(reader, writer, request)
                times.append(time.perf_counter() - start)
                if status != 200:
                    raise RuntimeError(f"status {status}")
        finally:
            writer.close()
        return times

    results = await asyncio.gather(*(poller() for _ in range(pollers)))
    return [t for times in results for t in times]


def _upload(base: str, photos: list[bytes]) -> float:
    files = [("images", (f"photo_{i}.jpg", data, "image/jpeg")) for i, data in enumerate(photos)]
    start = time.perf_counter()
    response = httpx.post(f"{base}/v1/jobs", files=files, timeout=120)
    elapsed = time.perf_counter() - start
    if response.status_code != 202:
        raise RuntimeError(f"upload refused: {response.text}")
    return elapsed


def run(quick: bool) -> str:
    """Measure and return a markdown section."""
    rounds, uploads = (5, 2) if quick else (20, 5)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-service-") as tmp:
        folder = Path(tmp)
        url, embedded = _redis_url(folder)
        redis.Redis.from_url(url).flushdb()
        port = free_port()
        server = _start_server(url, folder, port)
        base = f"http://127.0.0.1:{port}"
        try:
            small = [_photo(320, 240, i) for i in range(3)]
            files = [("images", (f"s{i}.jpg", d, "image/jpeg")) for i, d in enumerate(small)]
            job_id = httpx.post(f"{base}/v1/jobs", timeout=30, files=files).json()["id"]
            single = sorted(t * 1000 for t in asyncio.run(_poll(port, job_id, 5 * rounds, 1)))
            wall = time.perf_counter()
            latencies = asyncio.run(_poll(port, job_id, rounds, POLLERS))
            wall = time.perf_counter() - wall
            photos = [_photo(4000, 3000, i) for i in range(9)]
            upload_times = [_upload(base, photos) for _ in range(uploads)]
        finally:
            server.terminate()
            server.wait(30)
            redis.Redis.from_url(url).flushdb()
            if embedded is not None:
                embedded.stop()
    ms = sorted(t * 1000 for t in latencies)
    p99 = ms[min(len(ms) - 1, int(round(0.99 * (len(ms) - 1))))]
    megabytes = sum(len(p) for p in photos) / 2**20
    return "\n".join([
        "## Service",
        "",
        f"Command: `.venv/bin/python -m benchmarks.bench_service{' --quick' if quick else ''}` "
        f"(uvicorn, one process, on 127.0.0.1; Redis {'embedded' if embedded else 'local'}; "
        f"{os.cpu_count()} CPU cores shared with the client; load average before the run "
        f"{load:.1f}).",
        "",
        "| measure | value |",
        "| --- | --- |",
        f"| GET /v1/jobs/{{id}}, {POLLERS} concurrent pollers x {rounds} requests: median | "
        f"{statistics.median(ms):.1f} ms |",
        f"| same: p99 | {p99:.1f} ms |",
        f"| same: throughput | {len(ms) / wall:.0f} requests/s |",
        f"| GET /v1/jobs/{{id}}, one poller x {len(single)} requests: median | "
        f"{statistics.median(single):.1f} ms |",
        f"| accept a 9-photo 12 MP upload ({megabytes:.1f} MiB JPEG), median of {uploads} | "
        f"{statistics.median(upload_times):.2f} s |",
        "",
    ])


if __name__ == "__main__":
    from benchmarks.run import area_main

    sys.exit(area_main(run, __doc__ or "", library=False, quick_help="fewer requests and uploads"))
