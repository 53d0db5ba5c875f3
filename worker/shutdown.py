"""A graceful stop: on SIGTERM the running job goes back to the queue and the process ends
within ``STOP_DEADLINE_S``, well inside the 10 s ``docker stop`` and Kubernetes allow.

The job's progress adapter sees ``STOPPING`` at its next cancel check (the core checks between
steps, about once a second at most), the runner writes the job's files back and hands the job
back (``JobStore.hand_back``: queued at the front, no attempt counted), and the task sends its
wake-up again. A step that does not return in time is cut short: the process hands the job back
itself and exits; the job resumes from its last checkpoint on the next worker.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger(__name__)

STOPPING = threading.Event()
"""Set once this worker process was asked to stop."""
STOP_DEADLINE_S = 5.0
"""Seconds after SIGTERM by which the process has handed its job back and exited."""
SIGNAL_TAKERS = ("pycolmap",)
"""Native libraries the pipeline imports that take SIGTERM over at import (COLMAP's glog failure
handler dumps a stack and kills the process, or hangs symbolising it), so a stop request would
never reach the job."""
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def reclaim_stop_signals() -> None:
    """Import the ``SIGNAL_TAKERS`` now, then give the stop signals back to Python's handlers
    (the worker's own, Celery's). Call from the main thread before the first job."""
    for name in SIGNAL_TAKERS:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    if threading.current_thread() is not threading.main_thread():
        log.warning("stop signals not reclaimed: not on the main thread")
        return
    for sig in STOP_SIGNALS:
        handler = signal.getsignal(sig)
        if handler is not None:  # re-installing puts Python's trampoline back in the kernel
            signal.signal(sig, handler)


class Holder(Protocol):
    """What the deadline needs of the worker (``worker.liveness.Liveness``)."""

    def abandon(self) -> None:
        """Hand the held job back and queue its wake-up again (best effort)."""


def end_process(code: int = 0) -> None:
    """Flush the logs and end the process now, skipping the interpreter's teardown (the native
    libraries' clean-up takes seconds of the 10 a stop may use, for nothing: every job and
    message is settled by then)."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def request_stop(holder: Holder, deadline_s: float = STOP_DEADLINE_S,
                 exit_process: Callable[[int], object] = os._exit) -> threading.Timer:
    """Ask the running job to stop at its next step; past ``deadline_s`` give it back and end
    the process. Returns the deadline's timer (cancelled by a clean exit's interpreter end)."""
    if not STOPPING.is_set():
        log.warning("stopping: the running job (if any) goes back to the queue")
    STOPPING.set()

    def expire() -> None:
        log.error("still running %.0f s after the stop request; giving the job back and "
                  "exiting", deadline_s)
        try:
            holder.abandon()
        finally:
            exit_process(0)

    timer = threading.Timer(deadline_s, expire)
    timer.daemon = True
    timer.start()
    return timer
