"""What this server runs on, and what follows from it: the device the workers train on, the
default preset, and each preset's expected job time from the ETA table.

The API never imports torch, so it learns the workers' device from their heartbeats (each
announces ``device``: "cpu" or "cuda"). The default preset follows it unless the deployment
names one: ``preview`` finishes in minutes without a GPU, ``standard`` is the quality default
with one.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

import redis

from app.settings import AUTO_PRESET, Settings
from app.state.claims import Workers
from app.state.eta import DEFAULT_STAGE_SECONDS, StageHistory, expected_job_seconds, preset_history

log = logging.getLogger(__name__)

GPU_PRESET = "standard"  # the quality default, about a minute a job on one GPU
CPU_PRESET = "preview"  # a usable result in minutes on two CPU cores


@dataclass(frozen=True)
class PresetTime:
    """A preset's expected seconds for a whole job on this server's device.

    ``seconds``: measured on this server when ``measured``, else the ETA table's default for
    the device; None when neither exists. ``measured``: a worker here has timed jobs of it.
    """

    seconds: float | None
    measured: bool


def serving_device(workers: Workers, setting: str) -> str:
    """"cuda" or "cpu": where jobs will run.

    Args:
        workers: the live workers' heartbeats.
        setting: ``Settings.device`` ("auto", "cpu" or "cuda").

    Returns:
        The setting when it names a device; for "auto", "cuda" when a live worker announces a
        GPU, else "cpu" (also while Redis does not answer or no worker is up).
    """
    if setting != "auto":
        return setting
    try:
        devices = workers.devices()
    except redis.RedisError as exc:
        log.warning("worker devices unreadable: %s", exc)
        return "cpu"
    return "cuda" if "cuda" in devices else "cpu"


def default_preset(settings: Settings, device: str) -> str:
    """The preset of a job that names none: the deployment's choice, else by device."""
    if settings.default_preset != AUTO_PRESET:
        return settings.default_preset
    return GPU_PRESET if device == "cuda" else CPU_PRESET


def preset_times(history: StageHistory, presets: Iterable[str], device: str
                 ) -> dict[str, PresetTime]:
    """Each preset's expected job seconds on ``device``: measured here, else the table.

    Args:
        history: measured stage seconds (Redis); unreadable: the table alone.
        presets: the preset names.
        device: "cpu" or "cuda".

    Returns:
        Preset name -> its ``PresetTime``.
    """
    try:
        flat = history.measured(device)
    except redis.RedisError as exc:
        log.warning("measured stage times unreadable: %s", exc)
        flat = {}
    table = DEFAULT_STAGE_SECONDS.get(device, {})
    out = {}
    for preset in presets:
        measured = preset_history(flat, preset)
        if measured:
            out[preset] = PresetTime(expected_job_seconds(preset, device, measured), True)
        elif preset in table:
            out[preset] = PresetTime(float(sum(table[preset].values())), False)
        else:
            out[preset] = PresetTime(None, False)
    return out
