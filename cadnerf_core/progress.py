"""How the core reports progress and learns it should stop.

The core calls ``reporter(stage, done, total)`` between steps and ``check_cancel()`` at the same
places; adapters (a progress bar, Celery's custom states) live with the callers.
"""

from __future__ import annotations

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


class Progress:
    """Both callbacks together, with a helper that reports and checks in one call."""

    def __init__(self, reporter: ProgressReporter | None = None,
                 cancel: CancelCheck | None = None) -> None:
        self.reporter: ProgressReporter = reporter or no_progress
        self.cancel: CancelCheck = cancel or never_cancel

    def step(self, stage: str, done: int, total: int) -> None:
        """Report a finished step, then raise ``JobCancelled`` if the job should stop."""
        self.reporter(stage, done, total)
        self.check()

    def check(self) -> None:
        """Raise ``JobCancelled`` if the cancel callback says so."""
        if self.cancel():
            raise JobCancelled("the job was cancelled")
