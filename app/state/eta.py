"""Expected job times: default seconds per stage by preset and device, measured history, and
the running job's fraction done and seconds left.

The defaults hold until a worker has measured jobs of a preset on its kind of device; the
speed observed during a job then rescales the rest of it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import redis

from app.core import STAGES
from app.state import keys
from app.state.work import scaled

log = logging.getLogger(__name__)

DEVICES = ("cpu", "cuda")  # the kinds of device the tables and the history distinguish
FALLBACK_PRESET = "standard"  # the table of a job whose preset has none (the default preset's)
MEASURED_WEIGHT = 0.5  # exponential moving average of measured stage durations

# CPU: two cores (`preview` is `make run`'s demo), rounded up for slower cores; "retrieval"
# includes the start's three short hypothesis fits (about 9 s in all on 2 cores, retrieval and
# matching 1 to 2 s). CUDA: `standard` as in docs/bench_training_gpu.md (about 70 s a job on one
# H100); the others scaled by their step counts, since a GPU step costs about the same whatever
# its size.
DEFAULT_STAGE_SECONDS: dict[str, dict[str, dict[str, float]]] = {
    "cpu": {
        "preview": {"masks": 3, "retrieval": 10, "phase1": 3, "phase2": 33, "phase3": 110,
                    "render": 28, "export": 9},
        "standard": {"masks": 4, "retrieval": 10, "phase1": 250, "phase2": 1500, "phase3": 4000,
                     "render": 120, "export": 90},
        "paper": {"masks": 3, "retrieval": 10, "phase1": 300, "phase2": 5000, "phase3": 15000,
                  "render": 200, "export": 200},
    },
    "cuda": {
        "preview": {"masks": 3, "retrieval": 5, "phase1": 4, "phase2": 8, "phase3": 40,
                    "render": 6, "export": 6},
        "standard": {"masks": 3, "retrieval": 5, "phase1": 5, "phase2": 10, "phase3": 25,
                     "render": 12, "export": 12},
        "paper": {"masks": 3, "retrieval": 5, "phase1": 45, "phase2": 220, "phase3": 480,
                  "render": 20, "export": 25},
    },
}


def default_stage_seconds(preset: str, device: str) -> dict[str, float]:
    """The default table of ``preset`` on ``device`` ("cpu" or "cuda"; anything else: cpu).

    An unknown preset gets the ``FALLBACK_PRESET``'s table.
    """
    tables = DEFAULT_STAGE_SECONDS.get(device, DEFAULT_STAGE_SECONDS["cpu"])
    return dict(tables.get(preset, tables[FALLBACK_PRESET]))


def stage_table(preset: str, device: str, measured: Mapping[str, str | float],
                work: Mapping[str, float] | None = None) -> dict[str, float]:
    """Expected seconds per stage: the measured values where known, else the default table;
    scaled by a job's work per stage (``app.state.work.stage_work``; None: the preset's)."""
    table = default_stage_seconds(preset, device)
    for stage, seconds in measured.items():
        if stage in table:
            table[stage] = max(float(seconds), 1e-3)
    return scaled(table, work)


def expected_job_seconds(preset: str, device: str, measured: Mapping[str, str | float],
                         work: Mapping[str, float] | None = None) -> float | None:
    """Expected seconds of a whole job of ``preset`` (with ``work``, as ``stage_table``); None
    while no job of it was measured."""
    if not measured:
        return None
    return sum(stage_table(preset, device, measured, work).values())


def history_devices(device: str) -> tuple[str, ...]:
    """The devices whose measured times apply to workers configured with ``device``."""
    return ("cuda", "cpu") if device == "auto" else (device,)


def preset_history(flat: Mapping[str, str], preset: str) -> dict[str, str]:
    """One preset's measured stage seconds out of a device's history hash."""
    prefix = f"{preset}/"
    return {name[len(prefix):]: value for name, value in flat.items() if name.startswith(prefix)}


def first_history(histories: Iterable[tuple[str, Mapping[str, str]]],
                  preset: str) -> tuple[str, dict[str, str]]:
    """(device, measured) of the first device in ``histories`` that measured ``preset``."""
    first = ""
    for device, flat in histories:
        first = first or device
        measured = preset_history(flat, preset)
        if measured:
            return device, measured
    return first, {}


class StageHistory:
    """Measured stage seconds per preset and device, shared by all workers through Redis."""

    def __init__(self, client: redis.Redis) -> None:
        self._r = client

    def expected(self, preset: str, device: str,
                 work: Mapping[str, float] | None = None) -> dict[str, float]:
        """Expected seconds per stage on ``device``: measured where known, else the defaults;
        scaled by a job's ``work`` per stage."""
        try:
            flat = self._r.hgetall(keys.stage_seconds(device))
        except redis.RedisError as exc:  # the defaults still give an ETA
            log.warning("measured stage times unreadable: %s", exc)
            flat = {}
        return stage_table(preset, device, preset_history(flat, preset), work)  # type: ignore[arg-type]

    def measured(self, device: str) -> dict[str, str]:
        """Every preset's measured stage seconds on ``device``, fields ``<preset>/<stage>``
        (``preset_history`` picks one preset's); raises ``redis.RedisError``."""
        return dict(self._r.hgetall(keys.stage_seconds(device)))  # type: ignore[arg-type]

    def record(self, preset: str, device: str, durations: Mapping[str, float]) -> None:
        """Fold one job's measured stage durations into the averages of its preset."""
        if not durations:
            return
        names = [f"{preset}/{stage}" for stage in durations]
        old = self._r.hmget(keys.stage_seconds(device), names)
        new = {}
        for name, seconds, previous in zip(names, durations.values(), old, strict=True):  # type: ignore[arg-type]
            new[name] = (seconds if previous is None
                         else MEASURED_WEIGHT * seconds + (1 - MEASURED_WEIGHT) * float(previous))
        self._r.hset(keys.stage_seconds(device), mapping={k: f"{v:.4f}" for k, v in new.items()})


@dataclass
class _Report:
    """What the last report said of the running stage, for ``EtaModel.tick``."""

    at: float  # when it came
    part: float  # share of the stage done
    stage_seconds: float  # the stage's expected whole duration at this machine's speed
    future_s: float  # expected seconds of the stages after it
    start: float  # fraction of the job where the stage starts
    share: float  # the stage's share of the job's fraction


@dataclass
class EtaModel:
    """Fraction done and seconds left of a running job from its stage reports."""

    expected: dict[str, float]
    stage: str | None = None
    stage_started: float = 0.0
    durations: dict[str, float] = field(default_factory=dict)
    fraction: float = 0.0
    last: _Report | None = None
    _ticked: float = float("-inf")  # when ``tick`` last moved the bar

    def update(self, stage: str, done: int, total: int, now: float) -> tuple[float, float]:
        """Account for a report; returns (fraction done in [0, 1], seconds left). The bar
        moves on as between reports first (``tick``), so a report that is behind it (a stage
        slower than planned) never holds it still."""
        self.tick(now)
        return self._account(stage, done, total, now)

    def tick(self, now: float) -> tuple[float, float] | None:
        """Between two reports: the bar moves on toward the running stage's end, first at the
        stage's expected rate, then ever more slowly (the gap to the end falls as 1 / time),
        so it never stands still and never reaches the stage's end before the stage does (a
        stage slower than planned slows the bar; the next report never finds it at the end).
        Returns (fraction, seconds left); None before any report."""
        last = self.last
        if last is None:
            return None
        passed = max(now - max(last.at, self._ticked), 0.0)
        self._ticked = max(now, self._ticked)
        part = min(max((self.fraction - last.start) / max(last.share, 1e-12), 0.0), 1.0)
        remaining = max((1.0 - last.part) * last.stage_seconds, 1e-6)
        # gap' = -gap^2 / (gap_0 * remaining): gap = gap_0 / (1 + t / remaining) from a report.
        gap = 1.0 - part
        gap = gap / (1.0 + gap * passed / (max(1.0 - last.part, 1e-6) * remaining))
        part = 1.0 - gap
        self.fraction = max(self.fraction, min(last.start + last.share * part, 1.0))
        stage_left = max(remaining - max(now - last.at, 0.0), 0.0)
        return self.fraction, stage_left + last.future_s

    def _account(self, stage: str, done: int, total: int, now: float) -> tuple[float, float]:
        if stage != self.stage:
            if self.stage is not None:
                self.durations[self.stage] = now - self.stage_started
            self.stage, self.stage_started = stage, now
        part = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0
        order = list(STAGES) if stage in STAGES else [*STAGES, stage]
        position = order.index(stage)
        weights = [self.expected.get(s, 1.0) for s in order]
        start = sum(weights[:position]) / sum(weights)
        share = weights[position] / sum(weights)
        last = self.last
        if (part < 1.0 and last is not None and last.start >= start + share - 1e-9
                and self.fraction >= start + share - 1e-9):
            # The stage had reported its end and goes on with a count of its own (retrieval,
            # then the start's fits): the bar keeps moving into the next stage.
            stage_left = max((1.0 - last.part) * last.stage_seconds - (now - last.at), 0.0)
            return self.fraction, stage_left + last.future_s
        self.fraction = max(self.fraction, min(start + share * part, 1.0))
        stage_seconds, future = self._plan(order, position, part, now)
        self.last = _Report(now, part, stage_seconds, future, start, share)
        if part >= 1.0 and position + 1 < len(order):
            # A finished stage: until the next one reports, ticks move the bar into it.
            following = weights[position + 1]
            after = sum(weights[position + 2:])
            speed = future / (following + after) if following + after > 0 else 1.0
            self.last = _Report(now, 0.0, following * speed, after * speed, start + share,
                                following / sum(weights))
        return self.fraction, max((1.0 - part) * stage_seconds + future, 0.0)

    def finish(self, now: float) -> dict[str, float]:
        """Close the current stage; returns every stage's measured seconds."""
        if self.stage is not None:
            self.durations[self.stage] = now - self.stage_started
        return self.durations

    def _plan(self, order: list[str], position: int, part: float,
              now: float) -> tuple[float, float]:
        """(expected whole seconds of the current stage, expected seconds of the stages after
        it), both at the speed this job has shown so far."""
        measured = [(self.durations[s], self.expected.get(s, 1.0)) for s in order[:position]
                    if s in self.durations]
        # The finished stages tell how fast this machine is against the table: the current
        # stage's planned time is scaled by that before its own rate is known.
        expected_now = self.expected.get(order[position], 1.0) * _speed(measured)
        elapsed = now - self.stage_started
        observed_total = elapsed / part if part > 0 and elapsed > 0.2 else None
        # The observed rate of this stage is trusted more as the stage advances.
        if observed_total is None:
            stage_seconds = expected_now
        else:
            stage_seconds = part * observed_total + (1 - part) * expected_now
            measured.append((observed_total, self.expected.get(order[position], 1.0)))
        future = sum(self.expected.get(s, 1.0) for s in order[position + 1:]) * _speed(measured)
        return stage_seconds, future


def _speed(measured: list[tuple[float, float]]) -> float:
    """Measured over planned seconds of (measured, planned) pairs (1 without any), bounded."""
    spent = sum(m for m, _ in measured)
    planned = sum(e for _, e in measured)
    return min(max(spent / planned, 0.05), 100.0) if planned > 0 and spent > 0 else 1.0
