"""What object storage costs a ``preview`` job: upload, fetch, write-backs, results download.

One real job on a real S3 endpoint (``moto_server`` on 127.0.0.1, so the figures are the
service's own work: listing, hashing, HTTP, disk; a remote store adds its network time). The
API's side pushes the uploaded folder, a worker fetches it into a scratch folder, runs the job
with a write-back at every stage end (``worker.scratch.Scratch``) and a final one, and the API
fetches the finished results once to serve them.

Usage: ``python -m benchmarks.bench_store [--quick]`` (``--quick``: the tests' tiny config).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

from cadnerf_core.jobfolder import Transfer

ROOT = Path(__file__).resolve().parents[1]
COMMAND = "python -m benchmarks.bench_store"
VIEWS, SIZE = 6, 320  # six photos of the demo chair, 320 px (the demo sends 160 px)


class _Counting:
    """A storage wrapper counting the pushes (the write-backs) a job makes."""

    def __init__(self, storage: Any) -> None:
        self.storage = storage
        self.remote = storage.remote
        self.pushes: list[Transfer] = []

    def push(self, job_id: str, folder: Path) -> Transfer:
        moved: Transfer = self.storage.push(job_id, folder)
        self.pushes.append(moved)
        return moved

    def __getattr__(self, name: str) -> Any:
        return getattr(self.storage, name)


def _job_folder(folder: Path, quick: bool) -> None:
    """The photos and config of a preview job, as the API lays them out."""
    from cadnerf_cli.demo_photos import demo_mesh
    from cadnerf_core.evaluation.dataset import load_dataset, render_dataset
    from cadnerf_core.evaluation.jobio import write_job

    overrides: dict[str, Any] = {}
    if quick:
        from tests.configs import TINY_OVERRIDES

        overrides = TINY_OVERRIDES
    folder.parent.mkdir(parents=True, exist_ok=True)
    dataset = render_dataset(demo_mesh(folder.parent / "chair.ply"), folder.parent / "dataset",
                             n_views=VIEWS, size=SIZE, seed=0)
    write_job(folder, load_dataset(dataset), "preview", overrides)


def measure(quick: bool, library_dir: Path) -> dict[str, Any]:
    """Run one job through the store; the transfers of each step and the job's seconds."""
    from cadnerf_core.jobfolder import S3Storage
    from cadnerf_core.library.format import load_library
    from cadnerf_core.pipeline import run_job
    from cadnerf_core.progress import Progress, no_progress
    from tests.s3_fixture import S3_ENV, s3_client, start_moto
    from worker.scratch import Scratch

    work = Path(tempfile.mkdtemp(prefix="bench-store-"))
    moto, endpoint = start_moto(work / "moto.log")
    try:
        os.environ.update({**S3_ENV, "AWS_ENDPOINT_URL": endpoint})
        s3_client(endpoint).create_bucket(Bucket="bench")
        storage = _Counting(S3Storage("s3://bench/jobs"))
        job_id = str(uuid.uuid4())
        api_folder = work / "api" / job_id
        _job_folder(api_folder, quick)
        upload = storage.push(job_id, api_folder)
        storage.pushes.clear()
        scratch = Scratch(storage, job_id, work / "worker" / job_id, lambda: False)  # type: ignore[arg-type]
        scratch.fetch()
        started = time.perf_counter()
        run_job(scratch.folder, load_library(library_dir),
                Progress(scratch.reporting(no_progress)), "cpu")
        job_s = time.perf_counter() - started
        scratch.write_back()
        results = storage.fetch_results(job_id, work / "api-results" / job_id)
        stored = storage.job_bytes(job_id)
    finally:
        moto.terminate()
        moto.wait(10)
        shutil.rmtree(work, ignore_errors=True)
    return {"upload": upload, "fetch": scratch.fetched, "stage_pushes": storage.pushes[:-1],
            "final": storage.pushes[-1], "results": results, "job_s": job_s, "stored": stored}


def _row(step: str, moved: Transfer) -> str:
    return f"| {step} | {moved.files} | {moved.bytes / 1e6:.2f} | {moved.seconds:.2f} |"


def section(result: dict[str, Any], quick: bool) -> str:
    """The markdown section of one measurement."""
    stages = result["stage_pushes"]
    written = sum(stages, Transfer(0, 0, 0.0))
    total = (result["upload"] + result["fetch"] + written + result["final"]
             + result["results"])
    config = "the tests' tiny config" if quick else "preset `preview`"
    return "\n".join([
        "## Object storage: cost per job", "",
        f"Command: `{COMMAND}{' --quick' if quick else ''}`. One job ({config}, {VIEWS} "
        f"photos of the demo chair at {SIZE} px) through a real S3 endpoint (`moto_server` "
        "on 127.0.0.1: the figures are the service's own work; a remote store adds its "
        "network time).", "",
        "| step | files | MB | seconds |", "| --- | --- | --- | --- |",
        _row("upload (API to store, at the door)", result["upload"]),
        _row("fetch (worker's scratch copy)", result["fetch"]),
        _row(f"write-backs at stage ends ({len(stages)})", written),
        _row("final write-back (before `succeeded`)", result["final"]),
        _row("results fetched by the API (first download)", result["results"]),
        _row("all", total), "",
        f"The job itself took {result['job_s']:.1f} s; the store's steps add "
        f"{total.seconds:.2f} s ({100 * total.seconds / result['job_s']:.1f} %). The job "
        f"keeps {result['stored'] / 1e6:.2f} MB in the store (checkpoints included).", ""])


def run(quick: bool, library: Path | None = None) -> str:
    """``make bench``'s section."""
    return section(measure(quick, library or ROOT / "library_data" / "build"), quick)


def main(argv: list[str] | None = None) -> int:
    """Print the section (the command line of ``COMMAND``)."""
    from benchmarks.run import area_main

    return area_main(run, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
