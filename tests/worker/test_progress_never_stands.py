"""A whole job's progress, as the API shows it, moves at least every 10 s of work in every stage.

Time is a clock the test drives, not the wall clock: every unit of work the core announces (a
report or a cancel check, which every loop of every stage makes once a step, frame or chunk)
costs one second on it. The job runs for real on the tiny library; its reports go through the
worker's adapter (``worker.progress.JobProgress``) into Redis, from where the test reads the
fraction after each unit. The stage table given to the ETA is ten times too optimistic, as on a
machine slower than the one the table was made on: the bar must not run ahead to a stage's end
and stand there while the stage goes on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from app.state import STAGES, EtaModel, JobStore, keys
from cadnerf_core.progress import Progress
from tests.core.test_pipeline import write_job
from worker.progress import JobProgress

SECONDS_PER_UNIT = 1.0
MAX_STILL_S = 10.0


class WorkClock:
    """Seconds of work: advanced by the test once per unit the core announces."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_progress_moves_every_ten_seconds_of_work_in_every_stage(
        tmp_path: Path, tiny_library: Any, store: JobStore, new_job, clean_redis) -> None:
    from cadnerf_core.pipeline import run_job

    record = new_job()
    job_dir = store.job_dir(record.id)
    write_job(job_dir, tiny_library, overrides={"phase3": {"steps": 30}})
    clock = WorkClock()
    optimistic = {stage: 0.1 for stage in STAGES}  # ten times faster than one unit a step
    adapter = JobProgress(store, record.id, EtaModel(optimistic), clock=clock)
    trace: list[tuple[float, str, float]] = []  # (time, stage, fraction the API shows)

    def observe() -> None:
        shown = clean_redis.hget(keys.job(record.id), "progress")
        stage = adapter.eta.stage or "queued"
        trace.append((clock.now, stage, float(shown) if shown is not None else 0.0))

    def report(stage: str, done: int, total: int) -> None:
        clock.now += SECONDS_PER_UNIT
        adapter(stage, done, total)
        observe()

    def cancelled() -> bool:
        clock.now += SECONDS_PER_UNIT
        answer = adapter.cancelled()
        observe()
        return answer

    run_job(job_dir, tiny_library, Progress(report, cancelled, clock=clock), "cpu")

    assert {stage for _, stage, _ in trace} >= set(STAGES)
    still_since = trace[0][0]
    for (_, _, before), (now, stage, after) in zip(trace, trace[1:], strict=False):
        assert after >= before, f"progress went back in {stage}"
        if after > before:
            still_since = now
        assert now - still_since <= MAX_STILL_S, \
            f"progress stood at {after} for {now - still_since:.0f} s of work in {stage}"
    assert trace[-1][2] < 1.0 or trace[-1][1] == "export"
