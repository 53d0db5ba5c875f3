"""A worker whose interpreter is held (a native call keeps the GIL): its heartbeat says so in
the log, and past the stall limit the process writes every thread's stack and ends, instead of
beating no more and never returning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# A worker's liveness, then the interpreter held in C: sum() over a range never gives up the
# GIL (hours of work at this length), so only a watchdog that needs no interpreter can act.
HOLDER = """
import logging, sys, time
from app.settings import load_settings
from worker.liveness import Liveness
logging.basicConfig(level=logging.INFO, stream=sys.stderr)
settings = load_settings(redis_url=sys.argv[1], data_root=sys.argv[2], device="cpu")
liveness = Liveness(settings, "stalled-host", send=lambda job_id: None, startup_watch_s=0,
                    stall_exit_s=float(sys.argv[3]))
liveness.start()
time.sleep(2.0)  # a few beats first
def held_in_c():
    return sum(range(int(sys.argv[4])))
held_in_c()
print("returned", flush=True)
"""


def test_a_held_interpreter_ends_the_worker_with_its_stacks(tmp_path: Path, redis_url: str,
                                                            clean_redis: object) -> None:
    done = subprocess.run([sys.executable, "-c", HOLDER, redis_url, str(tmp_path), "3",
                           str(10**13)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert "returned" not in done.stdout
    assert done.returncode == 1, done.stderr[-2000:]
    assert "Timeout" in done.stderr and "held_in_c" in done.stderr, done.stderr[-2000:]


def test_a_native_crash_leaves_its_stack(tmp_path: Path, redis_url: str,
                                         clean_redis: object) -> None:
    crash = HOLDER.replace("\nheld_in_c()", "\nimport ctypes; ctypes.string_at(0)")
    done = subprocess.run([sys.executable, "-c", crash, redis_url, str(tmp_path), "300", "1"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode < 0 and "Segmentation fault" in done.stderr, done.stderr[-2000:]


def test_a_beat_late_enough_for_the_claim_to_lapse_is_logged(
        tmp_path: Path, redis_url: str, clean_redis: object,
        caplog: pytest.LogCaptureFixture) -> None:
    from app.settings import load_settings
    from app.state import HEARTBEAT_EVERY_S, HEARTBEAT_TTL_S
    from worker.liveness import Liveness

    settings = load_settings(redis_url=redis_url, data_root=tmp_path, device="cpu")
    liveness = Liveness(settings, "host", send=lambda job_id: None, stall_exit_s=None)
    liveness._job = "job-1"
    with caplog.at_level("WARNING", logger="worker.liveness"):
        liveness._note_stall(0.5)  # on time, as far as the claim goes
        assert not caplog.records
        liveness._note_stall(HEARTBEAT_TTL_S - HEARTBEAT_EVERY_S + 0.1)
    assert len(caplog.records) == 1
    message = caplog.records[0].getMessage()
    assert "held the interpreter" in message and "job-1" in message
