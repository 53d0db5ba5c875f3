"""Progress: the ETA tables and model (app.state), the adapter's throttled writes to Redis,
cancel checks."""

from __future__ import annotations

import json
import time

import pytest

from app.state import (
    DEFAULT_STAGE_SECONDS,
    STAGES,
    EtaModel,
    JobStore,
    StageHistory,
    connect,
    default_stage_seconds,
    keys,
)
from worker.progress import JobProgress

EXPECTED = {"masks": 1.0, "retrieval": 1.0, "phase1": 2.0, "phase2": 4.0, "phase3": 8.0,
            "render": 2.0, "export": 2.0}  # 20 s in all


def test_fraction_is_weighted_by_expected_stage_time() -> None:
    eta = EtaModel(dict(EXPECTED))
    fraction, left = eta.update("masks", 1, 1, now=0.0)
    assert fraction == pytest.approx(1 / 20)
    fraction, _ = eta.update("phase2", 2, 4, now=2.0)  # masks..phase1 done (4 s) + half of 4 s
    assert fraction == pytest.approx(6 / 20)
    fraction, _ = eta.update("phase1", 1, 2, now=2.0)  # going back never lowers the fraction
    assert fraction == pytest.approx(6 / 20)
    fraction, _ = eta.update("phase1", 1, 2, now=3.0)  # the bar moves on with time alone
    assert 6 / 20 + 0.01 < fraction < 8 / 20


def test_eta_follows_the_observed_speed() -> None:
    eta = EtaModel(dict(EXPECTED))
    _, table_left = eta.update("phase3", 0, 10, now=0.0)
    assert table_left == pytest.approx(8 + 2 + 2)  # no observation yet: the table
    # Observed: phase3 runs twice as slow as planned (half done after 8 s instead of 4 s).
    _, left = eta.update("phase3", 5, 10, now=8.0)
    slow = 0.5 * 16 * 0.5 + 0.5 * 8 * 0.5 + (2 + 2) * 2
    assert left == pytest.approx(slow)
    assert left > 8  # slower than the table's 4 + 4 s


def test_finished_stages_scale_the_plan_of_the_next_one() -> None:
    """A machine that ran the first stages four times faster than the table is expected to
    run the next one four times faster too, before that stage's own rate is known."""
    eta = EtaModel(dict(EXPECTED))
    eta.update("masks", 0, 1, now=0.0)
    eta.update("retrieval", 0, 1, now=0.25)
    eta.update("phase1", 0, 2, now=0.5)
    eta.update("phase2", 0, 4, now=1.0)  # masks, retrieval, phase1: 1 s against 4 planned
    _, left = eta.update("phase3", 0, 10, now=2.0)  # phase2: 1 s against 4
    assert left == pytest.approx((8 + 2 + 2) / 4)
    # Its own rate then takes over: half done in 4 s (the plan at the old speed) is slower.
    _, later = eta.update("phase3", 5, 10, now=6.0)
    assert later > (8 / 4) * 0.5 + (2 + 2) / 4


def test_measured_stage_times_replace_the_defaults_of_their_device(clean_redis) -> None:
    history = StageHistory(clean_redis)
    defaults = default_stage_seconds("preview", "cpu")
    assert history.expected("preview", "cpu") == defaults
    history.record("preview", "cpu", {"phase2": 10.0})
    history.record("preview", "cpu", {"phase2": 20.0})
    table = history.expected("preview", "cpu")
    assert table["phase2"] == pytest.approx(15.0) and table["masks"] == defaults["masks"]
    assert history.expected("preview", "cuda") == default_stage_seconds("preview", "cuda")
    assert history.expected("standard", "cpu") == default_stage_seconds("standard", "cpu")


def test_the_default_tables_know_the_device_and_every_stage() -> None:
    for device in ("cpu", "cuda"):
        for preset, table in DEFAULT_STAGE_SECONDS[device].items():
            assert set(table) == set(STAGES), (device, preset)
    # A standard job on a GPU takes about a minute; on two CPU cores, hours.
    assert 50 < sum(default_stage_seconds("standard", "cuda").values()) < 100
    assert sum(default_stage_seconds("standard", "cpu").values()) > 3600
    for preset in ("preview", "standard", "paper"):
        assert (sum(default_stage_seconds(preset, "cuda").values())
                < sum(default_stage_seconds(preset, "cpu").values()))


def test_an_unknown_preset_still_gets_an_estimate() -> None:
    assert "test" not in DEFAULT_STAGE_SECONDS["cpu"]
    for device in ("cpu", "cuda"):
        table = default_stage_seconds("custom", device)
        assert table == default_stage_seconds("standard", device)
        eta = EtaModel(table)
        _, left = eta.update("masks", 0, 1, now=0.0)
        assert left == pytest.approx(sum(table.values()))


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_reports_reach_redis_throttled_and_state_json_on_stage_changes(store: JobStore,
                                                                       new_job,
                                                                       clean_redis) -> None:
    record = new_job()
    clock = Clock()
    sent: list[dict] = []
    progress = JobProgress(store, record.id, EtaModel(dict(EXPECTED)), clock=clock,
                           celery_update=sent.append, throttle_s=0.5, mirror_every_s=5.0)
    progress("phase1", 1, 4)
    first = clean_redis.hgetall(keys.job(record.id))
    assert first["stage"] == "phase1" and float(first["progress"]) == pytest.approx(2.5 / 20)
    state = json.loads((store.job_dir(record.id) / "state.json").read_text())
    assert state["stage"] == "phase1"
    clock.now += 0.1
    progress("phase1", 2, 4)  # within the throttle window: not written
    assert float(clean_redis.hget(keys.job(record.id), "progress")) == pytest.approx(2.5 / 20)
    clock.now += 0.5
    progress("phase1", 3, 4)
    assert float(clean_redis.hget(keys.job(record.id), "progress")) == pytest.approx(3.5 / 20)
    assert [s["done"] for s in sent] == [1, 3] and sent[-1]["eta_s"] > 0


def test_between_reports_the_eta_moves_on_with_the_cancel_checks(store: JobStore, new_job,
                                                                  clean_redis) -> None:
    """Between two reports the core's cancel checks move the fraction up and the seconds left
    down; a stage far slower than planned keeps moving, ever more slowly, without reaching
    its end (the bar must not stand at a stage's end while the stage goes on)."""
    record = new_job()
    clock = Clock()
    progress = JobProgress(store, record.id, EtaModel(dict(EXPECTED)), clock=clock, tick_s=2.0)
    progress("phase3", 0, 10)  # 8 + 2 + 2 s left, 8 s of 20 done
    first = clean_redis.hgetall(keys.job(record.id))
    clock.now += 1.0
    progress.cancelled()  # within tick_s: nothing written
    assert clean_redis.hget(keys.job(record.id), "eta_s") == first["eta_s"]
    clock.now += 2.0
    progress.cancelled()
    moved = clean_redis.hgetall(keys.job(record.id))
    assert float(moved["eta_s"]) == pytest.approx(float(first["eta_s"]) - 3.0)
    assert float(first["progress"]) < float(moved["progress"]) < 16 / 20
    seen = [float(moved["progress"])]
    for _ in range(30):  # far past the plan: still moving, never at the stage's end
        clock.now += 10.0
        progress.cancelled()
        seen.append(float(clean_redis.hget(keys.job(record.id), "progress")))
    assert all(b > a for a, b in zip(seen, seen[1:], strict=False)), seen
    assert seen[-1] < 16 / 20
    assert float(clean_redis.hget(keys.job(record.id), "eta_s")) >= 2 + 2


def test_a_slow_stage_moves_the_bar_every_few_seconds_and_reports_catch_up() -> None:
    """A stage ten times slower than planned, reporting once a second (``Progress.advance``)
    with ticks in between, on a clock the test drives: the fraction changes at every write,
    and no report ever finds the bar ahead of it."""
    eta = EtaModel(dict(EXPECTED))
    now, steps, last_fraction = 0.0, 80, -1.0
    eta.update("phase3", 0, steps, now)
    for done in range(1, steps + 1):
        for _ in range(4):  # ticks between two reports, each 0.25 s apart
            now += 0.25
            ticked = eta.tick(now)
            assert ticked is not None
            assert ticked[0] > last_fraction
            last_fraction = ticked[0]
        fraction, left = eta.update("phase3", done, steps, now)
        assert fraction == pytest.approx(max(last_fraction, 8 / 20 + 8 / 20 * done / steps))
        assert fraction < 16 / 20 or done == steps
        assert left > 0
        last_fraction = fraction


def test_cancel_flag_and_deadline(store: JobStore, new_job) -> None:
    record = new_job()
    clock = Clock()
    progress = JobProgress(store, record.id, EtaModel(dict(EXPECTED)), clock=clock)
    assert progress.cancelled() is False
    store.request_cancel(record.id)
    assert progress.cancelled() is False  # checked at most every 0.25 s
    clock.now += 0.3
    assert progress.cancelled() is True and progress.timed_out is False
    late = JobProgress(store, new_job().id, EtaModel(dict(EXPECTED)), deadline=time.time() - 1)
    assert late.cancelled() is True and late.timed_out is True


def test_a_deleted_job_counts_as_cancelled_and_is_not_recreated(store: JobStore, new_job,
                                                                 clean_redis) -> None:
    record = new_job()
    store.delete(record)
    progress = JobProgress(store, record.id, EtaModel(dict(EXPECTED)))
    progress("phase1", 1, 2)
    assert clean_redis.exists(keys.job(record.id)) == 0
    assert progress.cancelled() is True


def test_redis_going_away_does_not_stop_the_job(store: JobStore, new_job, clean_redis) -> None:
    from app.embedded import free_port

    record = new_job()
    down = JobStore(connect(f"redis://127.0.0.1:{free_port()}/0"), store.data_root)
    clock = Clock()
    sent: list[dict] = []
    progress = JobProgress(down, record.id, EtaModel(dict(EXPECTED)), clock=clock,
                           celery_update=sent.append, retry_s=2.0)
    progress("phase1", 1, 4)  # the write fails: logged, not raised
    assert progress.redis_failures == 1 and sent == []
    assert progress.cancelled() is False  # the check is skipped while Redis is away
    clock.now += 0.6
    progress("phase1", 2, 4)  # inside the back-off: not even tried
    assert progress.redis_failures == 1
    clock.now += 2.0
    progress("phase1", 3, 4)  # tried again after the back-off
    assert progress.redis_failures == 2
    progress.store = store  # Redis is back
    clock.now += 2.1
    progress("phase2", 1, 4)
    assert clean_redis.hget(keys.job(record.id), "stage") == "phase2"
    assert [s["stage"] for s in sent] == ["phase2"]


def test_a_stage_counting_again_after_its_end_leaves_the_bar_moving() -> None:
    """Retrieval reports its search done, then the start's fits report retrieval 1/3, 2/3:
    the bar, already handed to the next stage, keeps moving and never goes back."""
    eta = EtaModel(dict(EXPECTED))
    eta.update("masks", 1, 1, now=0.0)
    end_of_retrieval, _ = eta.update("retrieval", 2, 2, now=0.5)
    assert end_of_retrieval == pytest.approx(2 / 20)
    seen = [end_of_retrieval]
    for now, done in ((1.0, 1), (2.0, 2), (3.0, 3)):
        fraction, left = eta.update("retrieval", done, 3, now=now)
        seen.append(fraction)
        assert left > 0
    assert all(b > a for a, b in zip(seen, seen[1:], strict=False)), seen
    assert seen[-1] < 4 / 20  # within phase one's share: no report of it yet
