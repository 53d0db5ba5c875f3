"""`cadnerf serve` on its own: embedded Redis, a supervised worker, the API; clean shutdown."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO

import httpx
import pytest
import redis

from app.embedded import free_port

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def _ready_workers(url: str, timeout_s: float, exclude: frozenset[str] = frozenset()) -> list[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            response = httpx.get(f"{url}/readyz", timeout=2)
            workers = [w for w in response.json().get("workers", []) if w not in exclude]
            if response.status_code == 200 and workers:
                return workers
        except (httpx.HTTPError, ValueError):
            pass
        time.sleep(0.5)
    raise AssertionError(f"no ready worker at {url} within {timeout_s} s")


def _alive(pid: int) -> bool:
    """True while the process exists and is not a zombie (an orphan may wait to be reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _start_serve(tmp_path: Path, library: Path,
                 *extra: str) -> tuple[subprocess.Popen[bytes], str, IO[bytes]]:
    """`cadnerf serve` without a Redis URL (embedded Redis, its own worker); its log is open."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k != "CADNERF_REDIS_URL"}
    env.update(CADNERF_DATA_ROOT=str(tmp_path / "data" / "jobs"),
               CADNERF_LIBRARY_DIR=str(library), CADNERF_DEVICE="cpu", TMPDIR=str(tmp_path))
    log = (tmp_path / "serve.log").open("wb")
    serve = subprocess.Popen([sys.executable, "-m", "tests.tiny_cli", "serve", "--port",
                              str(port), *extra], cwd=ROOT, env=env, stdout=log,
                             stderr=subprocess.STDOUT)
    return serve, f"http://127.0.0.1:{port}", log


def _stop(serve: subprocess.Popen[bytes], log: IO[bytes], sig: signal.Signals) -> None:
    """Send ``sig`` to serve and wait for it to end (killed, and the test failed, after 60 s)."""
    serve.send_signal(sig)
    try:
        serve.wait(60)
    except subprocess.TimeoutExpired:
        serve.kill()
        raise
    finally:
        log.close()


def _embedded_redis_url(log: Path) -> str:
    found = re.search(r"embedded Redis on (redis://\S+)", log.read_text())
    assert found is not None, log.read_text()[-3000:]
    return found.group(1)


def test_serve_stops_its_worker_and_redis_on_sigterm(tmp_path: Path,
                                                     tiny_library_dir: Path) -> None:
    """SIGTERM alone (docker stop, systemd) ends serve, its worker and the embedded Redis."""
    serve, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        worker_pid = int(_ready_workers(url, 180)[0].rsplit("-", 1)[1])
        redis_url = _embedded_redis_url(tmp_path / "serve.log")
        redis_pid = int(redis.Redis.from_url(redis_url).info("server")["process_id"])
        serve.send_signal(signal.SIGTERM)
        assert serve.wait(60) == 0
    finally:
        if serve.poll() is None:
            serve.kill()
        log.close()
    give_up = time.monotonic() + 60  # serve has ended: its children are ending, or never will
    while (_alive(worker_pid) or _alive(redis_pid)) and time.monotonic() < give_up:
        time.sleep(0.2)
    assert not _alive(worker_pid) and not _alive(redis_pid), \
        "serve ended but left its worker or Redis running\n" \
        + (tmp_path / "serve.log").read_text()[-3000:]


def test_serve_runs_everything_and_restarts_a_dead_worker(tmp_path: Path,
                                                          tiny_library_dir: Path) -> None:
    serve, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        first = _ready_workers(url, 180)
        assert (tmp_path / "data" / "redis").is_dir()  # the embedded Redis keeps its data there
        pid = int(first[0].rsplit("-", 1)[1])
        os.kill(pid, signal.SIGTERM)  # the worker dies; the supervisor starts another
        second = _ready_workers(url, 120, exclude=frozenset(first))
        new_pid = int(second[0].rsplit("-", 1)[1])
        assert new_pid != pid and _alive(new_pid)
        assert httpx.get(f"{url}/", timeout=5).status_code == 200
    finally:
        _stop(serve, log, signal.SIGINT)
    time.sleep(1)
    text = (tmp_path / "serve.log").read_text()
    assert not _alive(new_pid), text[-3000:]
    # Quiet by default (`--verbose` shows them): no access log of the /readyz polls above, no
    # Celery banner, no superuser warning.
    assert "GET /readyz" not in text and "[queues]" not in text and "superuser" not in text, \
        text[-3000:]
    with pytest.raises(redis.ConnectionError):  # the embedded server is gone too
        redis.Redis.from_url(_embedded_redis_url(tmp_path / "serve.log"),
                             socket_connect_timeout=1).ping()
    assert list((tmp_path / "data" / "redis").glob("*.rdb"))  # and saved its data


PROGRESS_LINE = re.compile(r"^  (queued|running|succeeded|failed) ", re.M)


def test_the_demo_shows_its_progress_within_30_lines(tmp_path: Path,
                                                      tiny_library_dir: Path) -> None:
    """`make run`'s command: the address, Redis and the demo job, then its first progress line,
    with nothing scrolling over them (no access log, Celery banner, superuser or open-service
    warning)."""
    serve, url, log = _start_serve(tmp_path, tiny_library_dir, "--demo")
    try:
        deadline = time.monotonic() + 180
        text = ""
        while time.monotonic() < deadline and not PROGRESS_LINE.search(text):
            assert serve.poll() is None, text[-3000:]
            time.sleep(0.5)
            text = (tmp_path / "serve.log").read_text()
        found = PROGRESS_LINE.search(text)
        assert found is not None, text[-3000:]
        head = text[:found.start()]
        assert len(head.splitlines()) <= 30, head
        assert f"starting the service on {url}" in head and f"watch it at {url}/?job=" in head
        # On a loopback address an open service warns no one: the first run shows no warning.
        assert "warning" not in head.lower(), head
    finally:
        _stop(serve, log, signal.SIGTERM)
