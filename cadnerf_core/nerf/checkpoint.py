"""Checkpoints after every phase, written atomically (temporary file, then rename)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cadnerf_core.config import PipelineConfig
from cadnerf_core.jobfolder import JobFolder, ensure_folder
from cadnerf_core.nerf.grid import SkipGrid
from cadnerf_core.nerf.state import TrainState

PHASES = (1, 2, 3)


def checkpoint_path(job_dir: Path, phase: int) -> Path:
    """``checkpoints/phase{phase}.pt`` in the job folder (``JobFolder.checkpoint_path``)."""
    return JobFolder(job_dir).checkpoint_path(phase)


def save_checkpoint(job_dir: Path, phase: int, state: TrainState,
                    extra: dict[str, Any] | None = None) -> Path:
    """Save the state after ``phase``; ``extra`` holds JSON-able metadata (names, K, timings)."""
    path = checkpoint_path(job_dir, phase)
    ensure_folder(path.parent)  # never re-creates a deleted job's folder
    payload = {
        "phase": phase,
        "config": state.config.model_dump(mode="json"),
        "fields": {k: v.cpu() for k, v in state.fields.state_dict().items()},
        "poses": {k: v.cpu() for k, v in state.poses.state_dict().items()},
        "grid": state.grid.occupied.cpu(),
        "bound": state.grid.bound,
        "history": state.history,
        "extra": extra or {},
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def last_checkpoint(job_dir: Path) -> tuple[int, Path] | None:
    """The highest finished phase with a checkpoint, or None."""
    for phase in reversed(PHASES):
        path = checkpoint_path(job_dir, phase)
        if path.is_file():
            return phase, path
    return None


def load_payload(path: Path) -> dict[str, Any]:
    """Read a checkpoint file onto the CPU."""
    payload: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=False)
    return payload


def restore_state(payload: dict[str, Any], device: torch.device,
                  config: PipelineConfig | None = None) -> TrainState:
    """Rebuild a TrainState from a checkpoint payload (its own config unless one is given)."""
    cfg = config or PipelineConfig.model_validate(payload["config"])
    c2w_init = payload["poses"]["c2w_init"].numpy().astype(np.float64)
    grid = SkipGrid(payload["grid"].to(device), float(payload["bound"]))
    poses = dict(payload["poses"])
    # Saved before the focal factor existed: a factor of 1.
    poses.setdefault("focal_logit", torch.zeros(1))
    learned = bool(payload.get("extra", {}).get("learn_focal", False))
    state = TrainState.create(cfg, c2w_init, device, grid, learned)
    state.fields.load_state_dict(payload["fields"])
    state.poses.load_state_dict(poses)
    state.history = dict(payload.get("history", {}))
    return state
