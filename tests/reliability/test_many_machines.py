"""Many machines: the API and two workers as separate processes, each with its own empty data
root, sharing only Redis and an S3 endpoint (``moto_server``, a real HTTP server speaking S3).

A job succeeds and its artifacts download through the API exactly as the worker stored them; a
worker killed with -9 in the middle of phase two leaves the job to the other one, which fetches
it from the store and resumes after phase one; SIGTERM to a lone worker hands its running job
back within 10 s, and a fresh worker on another empty data root finishes it.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import redis

from app.state import JobStore, connect
from tests.configs import SIGTERM_LIMIT_S, tiny_request
from tests.redis_fixture import _with_db
from tests.reliability import jobs
from tests.reliability.support import (
    NEEDS_PIPELINE,
    STORAGE_DB,
    Proc,
    pipeline_ready,
    ready_workers,
    service_env,
    start_api,
    start_worker,
    wait_for,
)
from tests.s3_fixture import bucket_objects, s3_client

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not pipeline_ready(), reason=NEEDS_PIPELINE)]

PREFIX = "jobs"
LONG_PHASE2 = tiny_request(phase2={"steps": 800})  # long enough to be caught mid-phase


@dataclass
class Cluster:
    """An API and workers on separate data roots, one bucket, one Redis database."""

    url: str
    api: Proc
    workers: dict[str, Proc]
    folder: Path
    redis_url: str
    bucket: str
    endpoint: str
    library: Path

    def env(self, name: str) -> dict[str, str]:
        """The environment of the process ``name``: its own data root, the shared store."""
        env = service_env(self.redis_url, self.folder / name / "jobs", self.library,
                          storage_url=f"s3://{self.bucket}/{PREFIX}")
        env.update({"AWS_ENDPOINT_URL": self.endpoint, "AWS_ACCESS_KEY_ID": "testing",
                    "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"})
        return env

    def start_worker(self, name: str) -> Proc:
        """Start a worker on a fresh data root and wait until the API lists it."""
        before = set(ready_workers(self.url))
        proc = start_worker(self.env(name), self.folder / f"{name}.log")
        self.workers[name] = proc
        up = wait_for(lambda: bool(set(ready_workers(self.url)) - before), 180, 0.5)
        assert up, f"worker {name} did not come up\n{self.logs()}"
        return proc

    def data_root(self, name: str) -> Path:
        """The data root of process ``name``."""
        return self.folder / name / "jobs"

    def logs(self) -> str:
        """Every process's log end, for assertion messages."""
        parts = [f"--- api\n{self.api.tail()}"]
        parts += [f"--- {name}\n{proc.tail()}" for name, proc in self.workers.items()]
        return "\n".join(parts)

    def record_worker(self, job_id: str) -> str | None:
        """The heartbeat name of the worker running the job (from the job state)."""
        store = JobStore(connect(self.redis_url), self.folder)
        try:
            record = store.get(job_id)
            return record.worker if record is not None else None
        finally:
            store.close()


@pytest.fixture()
def cluster(rel_redis_url: str, tiny_library_dir: Path, tmp_path: Path, s3_bucket: str,
            moto_endpoint: str) -> Iterator[Cluster]:
    """The API alone; tests start the workers they need."""
    url = _with_db(rel_redis_url, STORAGE_DB)
    redis.Redis.from_url(url).flushdb()
    placeholder = Cluster("", None, {}, tmp_path, url, s3_bucket, moto_endpoint,  # type: ignore[arg-type]
                          tiny_library_dir)
    api, base = start_api(placeholder.env("api"), tmp_path / "api.log")
    placeholder.api, placeholder.url = api, base
    yield placeholder
    for proc in placeholder.workers.values():
        proc.stop()
    api.stop()
    redis.Redis.from_url(url).flushdb()


def _stored(cluster: Cluster, job_id: str) -> dict[str, int]:
    """Name in the job folder -> size of the job's objects in the bucket."""
    start = f"{PREFIX}/{job_id}/"
    return {key[len(start):]: size
            for key, size in bucket_objects(cluster.endpoint, cluster.bucket, start).items()}


def _object(cluster: Cluster, job_id: str, name: str) -> bytes:
    body = s3_client(cluster.endpoint).get_object(Bucket=cluster.bucket,
                                                  Key=f"{PREFIX}/{job_id}/{name}")["Body"]
    data: bytes = body.read()
    return data


def _worker_pid(name: str) -> int:
    return int(name.rsplit("-", 1)[1])


def _assert_downloads_match_the_store(cluster: Cluster, job_id: str) -> list[str]:
    result = httpx.get(f"{cluster.url}/v1/jobs/{job_id}/result", timeout=30)
    assert result.status_code == 200, result.text
    assert result.json() == json.loads(_object(cluster, job_id, "result.json"))
    artifacts: list[str] = result.json()["artifacts"]
    assert {"results.zip", "mesh.glb", "orbit.mp4", "poses.json"} <= set(artifacts)
    base = f"{cluster.url}/v1/jobs/{job_id}/artifacts"
    for name in artifacts:
        answer = httpx.get(f"{base}/{name}", timeout=30)
        assert answer.status_code == 200, (name, answer.text)
        assert answer.content == _object(cluster, job_id, name), f"{name} differs from the store"
    whole = _object(cluster, job_id, "results.zip")
    part = httpx.get(f"{base}/results.zip", headers={"Range": "bytes=10-109"}, timeout=30)
    assert part.status_code == 206 and part.content == whole[10:110]
    return artifacts


def test_a_job_runs_on_a_worker_that_shares_no_disk_with_the_api(
        cluster: Cluster, photo_set: list[Path]) -> None:
    cluster.start_worker("worker_a")
    job = jobs.submit(cluster.url, photo_set, tiny_request())
    stored = _stored(cluster, job["id"])
    assert any(name.startswith("inputs/") for name in stored), stored
    assert not (cluster.data_root("api") / job["id"]).exists(), "the upload stayed on the API"
    final, _ = jobs.wait_state(cluster.url, job["id"], 600)
    assert final["state"] == "succeeded", f"{final}\n{cluster.logs()}"
    assert "checkpoints/phase3.pt" in _stored(cluster, job["id"])
    left = list(cluster.data_root("worker_a").rglob(f"*{job['id']}*"))
    assert not left, f"scratch copy left behind: {left}"
    _assert_downloads_match_the_store(cluster, job["id"])
    usage = httpx.get(f"{cluster.url}/v1/usage", timeout=10).json()
    assert usage["bytes_stored"] == sum(_stored(cluster, job["id"]).values())

    deleted = httpx.delete(f"{cluster.url}/v1/jobs/{job['id']}", timeout=30)
    assert deleted.status_code == 200, deleted.text
    assert _stored(cluster, job["id"]) == {}


def test_a_killed_workers_job_resumes_on_the_other_worker_from_the_store(
        cluster: Cluster, photo_set: list[Path]) -> None:
    cluster.start_worker("worker_a")
    cluster.start_worker("worker_b")
    job = jobs.submit(cluster.url, photo_set, LONG_PHASE2)
    jobs.wait_state(cluster.url, job["id"], 240, until=("running",), stage="phase2",
                    every_s=0.05)
    assert "checkpoints/phase1.pt" in _stored(cluster, job["id"])
    checkpoint = s3_client(cluster.endpoint).head_object(
        Bucket=cluster.bucket, Key=f"{PREFIX}/{job['id']}/checkpoints/phase1.pt")
    running_on = cluster.record_worker(job["id"])
    assert running_on, "no worker recorded on the running job"
    victim = _worker_pid(running_on)
    os.kill(victim, signal.SIGKILL)
    survivor = next(n for n, p in cluster.workers.items() if p.pid != victim)

    final, stages = jobs.wait_state(cluster.url, job["id"], 600, every_s=0.05)
    assert final["state"] == "succeeded", f"{final}\n{cluster.logs()}"
    assert "phase1" not in stages, stages
    assert cluster.workers[survivor].popen.poll() is None
    again = s3_client(cluster.endpoint).head_object(
        Bucket=cluster.bucket, Key=f"{PREFIX}/{job['id']}/checkpoints/phase1.pt")
    assert again["ETag"] == checkpoint["ETag"] and \
        again["LastModified"] == checkpoint["LastModified"], "phase one was run again"
    result = httpx.get(f"{cluster.url}/v1/jobs/{job['id']}/result", timeout=30).json()
    assert result["metrics"]["resumed_after_phase"] == 1, result["metrics"]
    _assert_downloads_match_the_store(cluster, job["id"])


def test_sigterm_hands_a_lone_workers_job_back_within_10_s(
        cluster: Cluster, photo_set: list[Path]) -> None:
    worker = cluster.start_worker("worker_a")
    job = jobs.submit(cluster.url, photo_set, LONG_PHASE2)
    jobs.wait_state(cluster.url, job["id"], 240, until=("running",), stage="phase2",
                    every_s=0.05)
    asked = time.monotonic()
    worker.popen.send_signal(signal.SIGTERM)
    try:
        worker.popen.wait(60)
    finally:
        took = time.monotonic() - asked
    assert took < SIGTERM_LIMIT_S, (
        f"`cadnerf worker` took {took:.1f} s to stop after SIGTERM; docker stop and Kubernetes "
        f"kill it after {SIGTERM_LIMIT_S:.0f} s\n{worker.tail()}")
    assert jobs.status(cluster.url, job["id"])["state"] == "queued", cluster.logs()

    cluster.start_worker("worker_b")
    final, stages = jobs.wait_state(cluster.url, job["id"], 600, every_s=0.05)
    assert final["state"] == "succeeded", f"{final}\n{cluster.logs()}"
    assert "phase1" not in stages, stages
    store = JobStore(connect(cluster.redis_url), cluster.folder)
    try:
        record = store.get(job["id"])
        assert record is not None and record.attempts == 0, "a graceful stop used an attempt"
    finally:
        store.close()
