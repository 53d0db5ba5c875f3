"""Fair order between owners: round-robin at claim time, kept through cancels and restarts."""

from __future__ import annotations

import time
import uuid
from pathlib import Path

from app.settings import load_settings
from app.state import JobRecord, JobState, JobStore
from tests.configs import TINY_PRESET
from worker import runner


def _submit(store: JobStore, owner: str) -> JobRecord:
    record = JobRecord(id=str(uuid.uuid4()), preset=TINY_PRESET, n_photos=3, owner=owner,
                       names=["a.png", "b.png", "c.png"], created_at=time.time())
    store.job_dir(record.id).mkdir()
    store.create(record)
    return record


def _owner_of(store: JobStore, job_id: str) -> str:
    record = store.get(job_id)
    assert record is not None
    return record.owner


def test_a_key_with_one_job_is_not_stuck_behind_another_keys_thirty(
        store: JobStore, redis_url: str) -> None:
    a_jobs = [_submit(store, "key-a") for _ in range(30)]
    b_job = _submit(store, "key-b")
    # One worker, one message per job, taken in the order they were sent (A's first). The
    # library does not exist, so each job fails right after it has started.
    settings = load_settings(redis_url=redis_url, data_root=store.data_root,
                             library_dir=Path("/nonexistent"))
    for token in [*a_jobs, b_job]:
        runner.execute(token.id, settings, store)
    started = {}
    for record in [*a_jobs, b_job]:
        final = store.get(record.id)
        assert final is not None and final.started_at is not None
        assert final.state == JobState.failed  # each ran exactly once, none left queued
        started[record.id] = final.started_at
    assert started[b_job.id] < started[a_jobs[2].id]
    order = sorted(started, key=started.__getitem__)
    assert order[:3] == [a_jobs[0].id, b_job.id, a_jobs[1].id]


def test_the_queue_position_follows_the_fair_order(store: JobStore) -> None:
    a_jobs = [_submit(store, "key-a") for _ in range(5)]
    b_jobs = [_submit(store, "key-b") for _ in range(2)]
    places = {i: e.position for i, e in
              store.queue_estimates([r.id for r in [*a_jobs, *b_jobs]]).items()}
    assert places[b_jobs[0].id] == 1 and places[b_jobs[1].id] == 3
    assert places[a_jobs[4].id] == 6
    taken = [store.take_next("w", 5.0) for _ in range(7)]
    assert [_owner_of(store, i) for i in taken if i] == ["key-a", "key-b"] * 2 + ["key-a"] * 3
    assert store.take_next("w", 5.0) is None


def test_a_key_arriving_later_joins_the_current_round(store: JobStore) -> None:
    a_jobs = [_submit(store, "key-a") for _ in range(6)]
    for _ in range(3):  # A's first three start: the round now running is A's third
        store.take_next("w", 5.0)
    b_job = _submit(store, "key-b")
    assert store.take_next("w", 5.0) == b_job.id
    assert store.take_next("w", 5.0) == a_jobs[3].id


def test_cancelled_and_deleted_queued_jobs_are_never_taken(store: JobStore) -> None:
    first, second, third = (_submit(store, "key-a") for _ in range(3))
    store.cancel(first.id)
    store.delete(second)
    assert store.take_next("w", 5.0) == third.id
    assert store.take_next("w", 5.0) is None


def test_a_job_is_taken_once_and_claimed_by_its_worker(store: JobStore) -> None:
    job = _submit(store, "key-a")
    assert store.take_next("w1", 5.0) == job.id
    assert store.take_next("w2", 5.0) is None
    record = store.get(job.id)
    assert record is not None and record.state == JobState.running and record.worker == "w1"
    assert store.claims.holder(job.id) == "w1"
    assert job.id in store.running_ids()


def test_the_queue_comes_back_after_redis_forgets_it(store: JobStore, clean_redis) -> None:
    jobs = [_submit(store, owner) for owner in ("key-a", "key-a", "key-b")]
    clean_redis.flushdb()
    for record in jobs:  # what any read does with a job Redis lost
        assert store.get(record.id) is not None
    taken = {store.take_next("w", 5.0) for _ in range(3)}
    assert taken == {r.id for r in jobs}
    assert store.take_next("w", 5.0) is None


def test_a_job_queued_again_after_its_worker_died_goes_first(store: JobStore) -> None:
    jobs = [_submit(store, "key-a") for _ in range(3)]
    orphan = store.take_next("dead", 0.001)
    assert orphan == jobs[0].id
    time.sleep(0.01)  # the claim lapses
    record = store.get(orphan)
    assert record is not None
    assert store.requeue_orphan(record, 3, "gone") == 1
    assert store.take_next("w", 5.0) == orphan


def test_an_owner_at_its_running_limit_is_passed_over_and_the_wake_up_kept(
        store: JobStore, redis_url: str) -> None:
    a_jobs = [_submit(store, "key-a") for _ in range(3)]
    b_job = _submit(store, "key-b")
    assert store.take_next("w1", 5.0, running_limit=1) == a_jobs[0].id
    assert store.take_next("w2", 5.0, running_limit=1) == b_job.id
    assert store.take_next("w3", 5.0, running_limit=1) is None
    settings = load_settings(redis_url=redis_url, data_root=store.data_root,
                             library_dir=Path("/nonexistent"), max_running_per_key=1)
    assert runner.execute(a_jobs[1].id, settings, store)["state"] == runner.DEFERRED
    queued = store.get(a_jobs[1].id)
    assert queued is not None and queued.state == JobState.queued
    assert store.take_next("w3", 5.0) == a_jobs[1].id  # no limit: taken


def test_a_cleanup_after_redis_forgot_everything_keeps_each_owners_order(
        store: JobStore, clean_redis) -> None:
    from app.jobs import cleanup

    jobs = [_submit(store, owner) for owner in ("key-a", "key-b", "key-a", "key-b", "key-a")]
    clean_redis.flushdb()
    assert cleanup(store, retention_s=3600.0) == 0
    taken = [store.take_next("w", 5.0) for _ in range(5)]
    assert taken == [jobs[0].id, jobs[1].id, jobs[2].id, jobs[3].id, jobs[4].id]
