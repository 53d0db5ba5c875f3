"""A succeeded job's outcome, read from its folder; artifact names and where they live.

Only names matching the allow-list are ever served, and the resolved path must stay inside the
job folder (no ``..``, no symbolic links leading out).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from app.errors import ApiError
from app.schemas import JobResult, ModelRef, PhotoResult
from app.state import JobRecord

ARTIFACT_RE = re.compile(
    r"^(orbit\.mp4|orbit\.gif|mesh\.glb|poses\.json|transforms\.json|metrics\.json"
    r"|retrieval\.json|config\.json|log\.txt|views/\d{3}\.png)$")
MEDIA_TYPES = {".mp4": "video/mp4", ".gif": "image/gif", ".glb": "model/gltf-binary",
               ".json": "application/json", ".png": "image/png", ".txt": "text/plain"}
LISTED = ("orbit.mp4", "orbit.gif", "mesh.glb", "poses.json", "transforms.json", "metrics.json",
          "retrieval.json", "config.json", "log.txt")


def artifact_path(job_dir: Path, name: str) -> Path:
    """The file behind an artifact name, checked against the allow-list and the job folder.

    Args:
        job_dir: the job's folder.
        name: e.g. ``orbit.mp4`` or ``views/003.png``.

    Returns:
        An existing file inside ``job_dir``.

    Raises:
        ApiError: 404 for a name off the list, a missing file, or a path leaving the folder.
    """
    missing = ApiError(404, "no_such_artifact", f"no artifact named {name[:80]!r}",
                       field="name", hint="see the result's `artifacts` for what exists")
    if not ARTIFACT_RE.match(name):
        raise missing
    root = job_dir.resolve()
    path = (root / name).resolve()
    if not path.is_relative_to(root) or not path.is_file():
        raise missing
    return path


def media_type(path: Path) -> str:
    """The Content-Type of an artifact."""
    return MEDIA_TYPES.get(path.suffix, "application/octet-stream")


def list_artifacts(job_dir: Path, job_id: str) -> dict[str, str]:
    """Artifact name -> download URL for every artifact present."""
    names = [n for n in LISTED if (job_dir / n).is_file()]
    views = job_dir / "views"
    if views.is_dir():
        names += sorted(f"views/{p.name}" for p in views.iterdir() if ARTIFACT_RE.match(
            f"views/{p.name}") and p.is_file())
    return {n: f"/v1/jobs/{job_id}/artifacts/{n}" for n in names}


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _pose_entries(poses: Any) -> list[dict[str, Any]]:
    if isinstance(poses, dict):
        for key in ("photos", "frames", "poses"):
            if isinstance(poses.get(key), list):
                return [p for p in poses[key] if isinstance(p, dict)]
    if isinstance(poses, list):
        return [p for p in poses if isinstance(p, dict)]
    return []


def _photo(index: int, name: str, match: dict[str, Any], pose: dict[str, Any]) -> PhotoResult:
    c2w = pose.get("c2w", match.get("c2w"))
    K = pose.get("K", pose.get("K_photo", match.get("K_photo")))
    discarded = bool(pose.get("discarded", match.get("discarded", c2w is None)))
    return PhotoResult(index=index, name=name, discarded=discarded,
                       iou=match.get("iou", pose.get("iou")),
                       view=match.get("view", pose.get("view")),
                       azimuth=match.get("azimuth", pose.get("azimuth")),
                       elevation=match.get("elevation", pose.get("elevation")),
                       c2w=None if discarded else c2w, K=None if discarded else K)


def _by_index(entries: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    out = {}
    for position, entry in enumerate(entries):
        index = entry.get("index", position)
        if isinstance(index, int):
            out[index] = entry
    return out


def read_result(record: JobRecord, job_dir: Path) -> JobResult:
    """Assemble a succeeded job's result from retrieval.json, poses.json and metrics.json.

    Raises:
        ApiError: 409 before the job succeeded.
    """
    if record.state != "succeeded":
        raise ApiError(409, "not_ready", f"the job is {record.state.value}; results exist once "
                       "it has succeeded", hint=f"poll /v1/jobs/{record.id} until state is "
                       "succeeded")
    retrieval = _read_json(job_dir / "retrieval.json")
    poses = _read_json(job_dir / "poses.json")
    metrics = _read_json(job_dir / "metrics.json")
    if not isinstance(retrieval, dict):
        retrieval = {}
    matches = _by_index(_pose_entries({"photos": retrieval.get("matches", [])}))
    pose_by_index = _by_index(_pose_entries(poses))
    photos = [_photo(i, name, matches.get(i, {}), pose_by_index.get(i, {}))
              for i, name in enumerate(record.names)]
    pose_model = poses.get("model_id") if isinstance(poses, dict) else None
    model_id = retrieval.get("model_id") or pose_model or "unknown"
    model = ModelRef(id=str(model_id), category=retrieval.get("category"))
    from cadnerf_core.config import AMBIGUOUS_HINT  # torch-free by contract

    warnings = []
    if retrieval.get("direction_ambiguous"):
        warnings.append(f"{AMBIGUOUS_HINT}: resubmit with the config field "
                        '{"overrides": {"retrieval": {"walk": "cw"}}}')
    return JobResult(id=record.id, model=model, photos=photos,
                     discarded=[p.name for p in photos if p.discarded],
                     metrics=metrics if isinstance(metrics, dict) else {},
                     artifacts=list_artifacts(job_dir, record.id), warnings=warnings)
