"""`cadnerf serve` on its own: embedded Redis, a supervised worker, the API; clean shutdown."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

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
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_serve_runs_everything_and_restarts_a_dead_worker(tmp_path: Path,
                                                          tiny_library_dir: Path) -> None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k != "CADNERF_REDIS_URL"}
    env.update(CADNERF_DATA_ROOT=str(tmp_path / "data" / "jobs"),
               CADNERF_LIBRARY_DIR=str(tiny_library_dir), CADNERF_DEVICE="cpu")
    log = (tmp_path / "serve.log").open("wb")
    serve = subprocess.Popen([sys.executable, "-m", "cadnerf_cli.main", "serve", "--port",
                              str(port)], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
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
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(60)
        except subprocess.TimeoutExpired:
            serve.kill()
            raise
        finally:
            log.close()
    time.sleep(1)
    text = (tmp_path / "serve.log").read_text()
    assert not _alive(new_pid), text[-3000:]
    redis_url = re.search(r"embedded Redis on (redis://\S+)", text)
    assert redis_url is not None
    with pytest.raises(redis.ConnectionError):  # the embedded server is gone too
        redis.Redis.from_url(redis_url.group(1), socket_connect_timeout=1).ping()
    assert list((tmp_path / "data" / "redis").glob("*.rdb"))  # and saved its data
