"""A live service for end-to-end tests: uvicorn on 127.0.0.1, one real `cadnerf worker` process,
a real Redis (tests/redis_fixture.py) and the tiny library (tests/conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


from app.embedded import free_port  # noqa: E402
from app.settings import Settings, load_settings  # noqa: E402


@dataclass
class LiveService:
    """A running API and worker."""

    url: str
    settings: Settings
    worker: subprocess.Popen[bytes]
    worker_log: Path

    def log_tail(self, chars: int = 4000) -> str:
        """The end of the worker's log, and its exit status once it has ended (for assertion
        messages)."""
        ended = self.worker.poll()
        status = "" if ended is None else f"\n[the worker process ended with status {ended}]"
        return self.worker_log.read_text(errors="replace")[-chars:] + status


def _start_api(settings: Settings, port: int) -> tuple[object, threading.Thread]:
    import uvicorn

    from app.main import create_app

    config = uvicorn.Config(create_app(settings), host="127.0.0.1", port=port,
                            log_level="warning", lifespan="on")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.started, "uvicorn did not start"
    return server, thread


def _wait_ready(url: str, worker: subprocess.Popen[bytes], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and worker.poll() is None:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return True
        except httpx.HTTPError:
            pass
        time.sleep(0.3)
    return False


@pytest.fixture(scope="module")
def live_service(tiny_library_dir: Path, redis_url: str,
                 tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveService]:
    """API + worker on a fresh data root on the CPU; tests send the suite's tiny config.

    The default preset is left to follow the device (CADNERF_DEFAULT_PRESET=auto), so the page
    offers what a CPU server offers."""
    import redis

    redis.Redis.from_url(redis_url).flushdb()
    folder = tmp_path_factory.mktemp("service")
    env = {**os.environ, "CADNERF_REDIS_URL": redis_url, "CADNERF_DATA_ROOT": str(folder / "jobs"),
           "CADNERF_LIBRARY_DIR": str(tiny_library_dir), "CADNERF_DEVICE": "cpu",
           "CADNERF_DEFAULT_PRESET": "auto", "OMP_NUM_THREADS": "1"}
    settings = load_settings(redis_url=redis_url, data_root=folder / "jobs",
                             library_dir=tiny_library_dir, device="cpu", default_preset="auto")
    log_path = folder / "worker.log"
    with log_path.open("wb") as log_file:
        worker = subprocess.Popen([sys.executable, "-m", "cadnerf_cli.main", "worker"], env=env,
                                  cwd=ROOT, stdout=log_file, stderr=subprocess.STDOUT)
    port = free_port()
    server, thread = _start_api(settings, port)
    service = LiveService(f"http://127.0.0.1:{port}", settings, worker, log_path)
    try:
        assert _wait_ready(service.url, worker, 180), f"worker not ready:\n{service.log_tail()}"
        yield service
    finally:
        server.should_exit = True  # type: ignore[attr-defined]
        thread.join(15)
        worker.terminate()
        try:
            worker.wait(30)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait(10)


@pytest.fixture(scope="module")
def photo_set(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Four 64 px RGBA renders of a box walked around (alpha = mask)."""
    import trimesh

    from cadnerf_core.evaluation.dataset import render_dataset

    folder = tmp_path_factory.mktemp("photos")
    mesh_path = folder / "box.ply"
    trimesh.creation.box((1.0, 0.6, 0.4)).export(mesh_path)
    dataset = render_dataset(mesh_path, folder / "dataset", n_views=4, size=64, seed=1)
    return sorted((dataset / "images").glob("*.png"))
