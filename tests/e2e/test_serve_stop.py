"""A graceful stop of `cadnerf serve` (embedded Redis and worker) with a job running: SIGTERM
ends every process within the 10 s `docker stop` and Kubernetes allow, and the job that was
running goes back to the queue and finishes after the next start, resuming after phase one."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from tests.configs import SIGTERM_LIMIT_S, tiny_request
from tests.e2e.test_serve import _alive, _ready_workers, _start_serve
from tests.reliability import jobs
from tests.reliability.support import render_photo_set

pytestmark = pytest.mark.slow

LONG_PHASE2 = tiny_request(phase2={"steps": 800})  # long enough to be caught mid-phase


def test_sigterm_stops_serve_in_10_s_and_the_job_finishes_after_a_restart(
        tmp_path: Path, tiny_library_dir: Path) -> None:
    photos = render_photo_set(tmp_path / "photos")
    serve, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        worker_pid = int(_ready_workers(url, 180)[0].rsplit("-", 1)[1])
        job = jobs.submit(url, photos, LONG_PHASE2)
        jobs.wait_state(url, job["id"], 240, until=("running",), stage="phase2", every_s=0.05)
        asked = time.monotonic()
        serve.send_signal(signal.SIGTERM)
        serve.wait(60)
        took = time.monotonic() - asked
    finally:
        if serve.poll() is None:
            serve.kill()
        log.close()
    text = (tmp_path / "serve.log").read_text()
    assert took < SIGTERM_LIMIT_S, (
        f"`cadnerf serve` took {took:.1f} s to stop after SIGTERM with a job running; docker "
        f"stop and Kubernetes kill it after {SIGTERM_LIMIT_S:.0f} s\n{text[-3000:]}")
    assert serve.returncode == 0 and not _alive(worker_pid), text[-3000:]

    again, url, log = _start_serve(tmp_path, tiny_library_dir)
    try:
        final, stages = jobs.wait_state(url, job["id"], 600, every_s=0.05)
        assert final["state"] == "succeeded", f"{final}\n{(tmp_path / 'serve.log').read_text()}"
        assert "phase1" not in stages, stages
    finally:
        again.send_signal(signal.SIGTERM)
        again.wait(60)
        log.close()
