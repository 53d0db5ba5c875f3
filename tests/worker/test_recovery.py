"""Jobs of dead workers: claims, orphan detection with a grace period, re-queueing, the bound."""

from __future__ import annotations

import time

from app.state import MAX_ATTEMPTS, JobState, JobStore, OrphanWatch, find_orphans, requeue
from worker import runner
from worker.runner import _FixedClaim


class Clock:
    """A manual monotonic clock."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _orphan(store: JobStore, new_job, worker: str = "host-1", attempts: int = 0):
    record = new_job()
    store.update(record.id, state=JobState.running, worker=worker, attempts=attempts)
    store.mirror(record.id)
    store.mark_running(record.id, True)
    return store.get(record.id)


def test_a_claim_is_exclusive_until_released(store: JobStore, new_job) -> None:
    job = new_job()
    assert store.claims.take(job.id, "a") and store.claims.take(job.id, "a")
    assert not store.claims.take(job.id, "b")
    store.claims.release(job.id, "b")  # not b's to release
    assert store.claims.holder(job.id) == "a"
    store.claims.release(job.id, "a")
    assert store.claims.take(job.id, "b")


def test_a_duplicate_delivery_of_a_claimed_job_is_dropped(store: JobStore, new_job,
                                                          redis_url) -> None:
    from app.settings import load_settings

    settings = load_settings(redis_url=redis_url, data_root=store.data_root)
    job = new_job()
    assert store.claims.take(job.id, "other-worker")
    assert runner.execute(job.id, settings, store)["state"] == "duplicate"
    after = store.get(job.id)
    assert after is not None and after.state == JobState.queued and after.started_at is None


def test_an_orphan_is_requeued_once_after_the_grace_period(store: JobStore, new_job) -> None:
    record = _orphan(store, new_job)
    sent: list[str] = []
    clock = Clock()
    watch = OrphanWatch(store, sent.append, grace_s=5.0, clock=clock)
    other = OrphanWatch(store, sent.append, grace_s=5.0, clock=clock)
    assert watch.check() == [] and other.check() == []  # first sighting: wait
    clock.now += 5.0
    assert watch.check() == [record.id]
    assert other.check() == []  # another process saw the same orphan: not sent twice
    assert sent == [record.id]
    after = store.get(record.id)
    assert after is not None and after.state == JobState.queued
    assert after.attempts == 1 and after.worker is None
    assert store.read_state_file(record.id).state == JobState.queued  # type: ignore[union-attr]
    assert record.id not in store.running_ids()
    assert store.queue_estimates([record.id])[record.id].position == 0  # back in the queue


def test_a_claimed_job_is_not_an_orphan_and_a_flicker_is_forgiven(store: JobStore,
                                                                  new_job) -> None:
    record = _orphan(store, new_job)
    sent: list[str] = []
    clock = Clock()
    watch = OrphanWatch(store, sent.append, grace_s=5.0, clock=clock)
    watch.check()  # orphaned for a moment (say Redis restarted)...
    store.claims.take(record.id, "host-1")  # ...then its worker's heartbeat re-claims it
    clock.now += 10.0
    assert watch.check() == [] and sent == []
    assert store.get(record.id).state == JobState.running  # type: ignore[union-attr]


def test_the_attempts_are_bounded(store: JobStore, new_job) -> None:
    record = _orphan(store, new_job, attempts=MAX_ATTEMPTS - 1)
    sent: list[str] = []
    assert requeue(store, record, sent.append) == "failed"
    after = store.get(record.id)
    assert after is not None and after.state == JobState.failed and sent == []
    assert str(MAX_ATTEMPTS) in (after.error or "")
    assert record.id not in store.running_ids() and store.queue_estimates([record.id]) == {}


def test_a_final_state_json_wins_over_a_stale_running_record(store: JobStore, new_job) -> None:
    record = _orphan(store, new_job)
    running = store.get(record.id)
    assert running is not None and running.state == JobState.running
    store.write_state_file(running.model_copy(update={"state": JobState.succeeded}))
    assert find_orphans(store) == []  # Redis still said running
    assert store.get(record.id).state == JobState.succeeded  # type: ignore[union-attr]


def test_a_failed_send_fails_the_job_instead_of_leaving_it_queued(store: JobStore,
                                                                 new_job) -> None:
    record = _orphan(store, new_job)

    def broken(_: str) -> None:
        raise ConnectionError("broker away")

    assert requeue(store, record, broken) == "failed"
    assert store.get(record.id).state == JobState.failed  # type: ignore[union-attr]
    assert store.queue_estimates([record.id]) == {}  # not left in the queue order


def test_the_fixed_claim_blocks_other_workers(store: JobStore, new_job) -> None:
    job = new_job()
    mine = _FixedClaim(store, ttl_s=60)
    assert mine.hold(job.id)
    assert not store.claims.take(job.id, "someone-else")
    mine.drop(job.id)
    assert store.claims.holder(job.id) is None


def test_a_deleted_job_is_never_brought_back(store: JobStore, new_job) -> None:
    """A late writer's state.json in a deleted job's folder, and its worker's heartbeat: the
    tombstone wins over both (no re-seed, not in the running set, the folder removed)."""
    record = _orphan(store, new_job)
    saved = (store.job_dir(record.id) / "state.json").read_bytes()
    store.delete(record)
    folder = store.job_dir(record.id)
    folder.mkdir()  # what a worker without the fix wrote after the delete
    (folder / "state.json").write_bytes(saved)
    store.mark_running(record.id, True)  # its heartbeat
    assert record.id not in store.running_ids()
    assert find_orphans(store) == [] and store.get(record.id) is None
    assert not folder.exists() and store.remove_trash() == 0


def test_the_heartbeat_announces_the_device_the_api_offers_presets_for(store: JobStore,
                                                                     redis_url: str) -> None:
    from app.settings import load_settings
    from worker.liveness import Liveness

    settings = load_settings(redis_url=redis_url, data_root=store.data_root, device="cpu")
    liveness = Liveness(settings, "host-cpu", send=lambda job_id: None, startup_watch_s=0)
    liveness.start()
    try:
        give_up = time.monotonic() + 60  # a guard against a hang: the first beat is at once
        while not store.workers.devices() and time.monotonic() < give_up:
            time.sleep(0.05)
        assert store.workers.devices() == ["cpu"], "no heartbeat announced the worker's device"
    finally:
        liveness.stop()
    assert store.workers.devices() == []


def test_a_stalled_queue_wakes_its_idle_workers(store: JobStore, new_job) -> None:
    """A queued job whose message was lost (Redis restarted empty) is not left waiting: once
    it has been first in the queue for STALL_S while a worker is idle, a message is sent."""
    from app.state.recovery import STALL_S

    record = new_job()
    sent: list[str] = []
    clock = Clock()
    watch = OrphanWatch(store, sent.append, grace_s=5.0, clock=clock)
    store.workers.beat("idle-1")
    assert watch.check() == [] and sent == []  # first sighting of this head
    clock.now += STALL_S - 1
    assert watch.check() == [] and sent == []  # not stalled yet
    clock.now += 1
    assert watch.check() == [record.id] and sent == [record.id]
    clock.now += 1
    assert watch.check() == [] and sent == [record.id]  # the next one waits STALL_S again
    busy = new_job()  # every live worker busy: nothing to wake
    store.update(busy.id, state=JobState.running, worker="idle-1")
    store.mark_running(busy.id, True)
    clock.now += 2 * STALL_S
    assert watch.check() == [] and sent == [record.id]


def test_the_heartbeats_a_killed_serve_saved_can_all_be_forgotten(store: JobStore) -> None:
    """`serve` restarting on a Redis saved by a killed one drops its dead workers' heartbeats,
    so readiness waits for the new worker instead of naming the old."""
    store.workers.beat("old-1", info={"device": "cpu"})
    store.workers.beat("old-2")
    assert store.workers.live() == ["old-1", "old-2"]
    assert store.workers.forget_all() == 2
    assert store.workers.live() == [] and store.workers.devices() == []
    store.workers.beat("new-3")
    assert store.workers.live() == ["new-3"]
