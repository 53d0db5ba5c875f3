"""How the core reports progress and learns it should stop.

The core calls ``reporter(stage, done, total)`` between steps and ``check_cancel()`` at the same
places; adapters (a progress bar, Celery's custom states) live with the callers.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

from cadnerf_core.errors import JobCancelled

STAGES = ("masks", "retrieval", "phase1", "phase2", "phase3", "render", "export")
"""The stages a job reports, in the order it runs them."""


class ProgressReporter(Protocol):
    """Receives (stage, done, total) whenever a step of ``stage`` finishes."""

    def __call__(self, stage: str, done: int, total: int) -> None: ...


CancelCheck = Callable[[], bool]


def no_progress(stage: str, done: int, total: int) -> None:
    """A reporter that ignores everything."""
    del stage, done, total


def never_cancel() -> bool:
    """A cancel check that never asks to stop."""
    return False


REPORT_INTERVAL_S = 1.0
"""Longest wait between two reports of a loop that calls ``Progress.advance`` every step."""


class Progress:
    """Both callbacks together, with helpers that report and check in one call.

    ``clock``: seconds (monotonic), for ``advance``'s interval.
    """

    def __init__(self, reporter: ProgressReporter | None = None,
                 cancel: CancelCheck | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 interval_s: float = REPORT_INTERVAL_S) -> None:
        self.reporter: ProgressReporter = reporter or no_progress
        self.cancel: CancelCheck = cancel or never_cancel
        self.clock = clock
        self.interval_s = interval_s
        self._last: tuple[str, float] | None = None  # (stage, clock) of the last report

    def step(self, stage: str, done: int, total: int) -> None:
        """Report a finished step, then raise ``JobCancelled`` if the job should stop."""
        self._last = (stage, self.clock())
        self.reporter(stage, done, total)
        self.check()

    def advance(self, stage: str, done: int, total: int) -> None:
        """A step of a long loop finished: report it when the stage is new, the loop is done
        or ``interval_s`` passed since the last report (else only check for cancelling), so
        a loop reports about once a second whatever its steps cost."""
        last = self._last
        if (last is None or last[0] != stage or done >= total
                or self.clock() - last[1] >= self.interval_s):
            self.step(stage, done, total)
        else:
            self.check()

    def check(self) -> None:
        """Raise ``JobCancelled`` if the cancel callback says so."""
        if self.cancel():
            raise JobCancelled("the job was cancelled")
