"""A succeeded job's outcome, read from its folder through the core's ``JobFolder``.

Only names on the folder's allow-list are ever served, and the resolved path must stay inside
the job folder (no ``..``, no symbolic links leading out).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote

from app.core import JobFolder, MaskRecord, StorageError, job_warnings, media_type, walk_order
from app.errors import ApiError
from app.schemas import JobResult, ModelRef, PhotoResult
from app.state import JobRecord, JobState, JobStore

log = logging.getLogger(__name__)

__all__ = ["artifact_path", "list_artifacts", "media_type", "read_result", "results_folder"]


def results_folder(store: JobStore, record: JobRecord) -> Path:
    """The folder on this machine holding a succeeded job's results.

    With object storage they are fetched from the store the first time (a succeeded job's
    files never change), so range requests, ETags and ``results.zip`` are served from a
    local file as on one machine.

    Raises:
        ApiError: 503 when the store cannot be reached.
    """
    folder = store.job_dir(record.id)
    if record.state != JobState.succeeded:
        return folder
    try:
        store.storage.fetch_results(record.id, folder)
    except StorageError as exc:
        log.error("job %s: results not fetched: %s", record.id, exc)
        raise ApiError(503, "storage_unavailable", "the job storage cannot be reached",
                       hint="try again later; the operator has to check the object store",
                       headers={"Retry-After": "30"}) from None
    return folder


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
    path = JobFolder(job_dir).artifact_path(name)
    if path is None:
        raise ApiError(404, "no_such_artifact", f"no artifact named {name[:80]!r}",
                       field="name", hint="see the result's `artifacts` for what exists")
    return path


def list_artifacts(job_dir: Path, job_id: str) -> dict[str, str]:
    """Artifact name -> download URL for every artifact present."""
    return {n: f"/v1/jobs/{job_id}/artifacts/{n}" for n in JobFolder(job_dir).artifacts()}


def _tolerant(read: Callable[[], Any]) -> Any:
    """A reader's answer, None when the file is unreadable (a result shows what it can)."""
    try:
        return read()
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


def _mask_links(mask: MaskRecord | None, artifacts: dict[str, str]) -> dict[str, Any]:
    """A photo's mask fields: source, warnings, and the URLs of its mask and overlay."""
    if mask is None:
        return {}
    return {"mask_source": mask.source, "mask_warnings": mask.warnings,
            "mask": artifacts.get(mask.mask),
            "overlay": artifacts.get(mask.overlay) if mask.overlay else None}


def _silhouette_url(model_id: Any, view: Any, perspective: Any) -> str | None:
    """The library route of a matched silhouette (None without a model or view)."""
    if not isinstance(model_id, str) or not isinstance(view, int):
        return None
    suffix = "?perspective=near" if perspective == "near" else ""
    return f"/v1/library/{quote(model_id, safe='')}/silhouette/{view}{suffix}"


def _photo(index: int, name: str, match: dict[str, Any], pose: dict[str, Any],
           links: dict[str, Any], silhouette: Callable[[Any], str | None]) -> PhotoResult:
    c2w = pose.get("c2w", match.get("c2w"))
    K = pose.get("K", pose.get("K_photo", match.get("K_photo")))
    discarded = bool(pose.get("discarded", match.get("discarded", c2w is None)))
    view = match.get("view", pose.get("view"))
    return PhotoResult(index=index, name=name, discarded=discarded,
                       iou=match.get("iou", pose.get("iou")), view=view,
                       azimuth=match.get("azimuth", pose.get("azimuth")),
                       elevation=match.get("elevation", pose.get("elevation")),
                       c2w=None if discarded else c2w, K=None if discarded else K,
                       silhouette=None if discarded else silhouette(view), **links)


def _by_index(entries: list[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    out = {}
    for position, entry in enumerate(entries):
        index = entry.get("index", position)
        if isinstance(index, int):
            out[index] = entry
    return out


def read_result(record: JobRecord, job_dir: Path) -> JobResult:
    """Assemble a succeeded job's result from its retrieval, poses, metrics and mask sources.

    Raises:
        ApiError: 409 before the job succeeded.
    """
    if record.state != "succeeded":
        raise ApiError(409, "not_ready", f"the job is {record.state.value}; results exist once "
                       "it has succeeded", hint=f"poll /v1/jobs/{record.id} until state is "
                       "succeeded")
    folder = JobFolder(job_dir)
    retrieval = _tolerant(folder.read_retrieval) or {}
    poses = _tolerant(folder.read_poses)
    metrics = _tolerant(folder.read_metrics)
    masks = {m.index: m for m in _tolerant(folder.read_mask_sources) or []}
    matches = _by_index(_pose_entries({"photos": retrieval.get("matches", [])}))
    pose_by_index = _by_index(_pose_entries(poses))
    artifacts = list_artifacts(job_dir, record.id)
    pose_model = poses.get("model_id") if isinstance(poses, dict) else None
    model_id = retrieval.get("model_id") or pose_model

    def silhouette(view: Any) -> str | None:
        return _silhouette_url(model_id, view, retrieval.get("perspective"))

    photos = [_photo(i, name, matches.get(i, {}), pose_by_index.get(i, {}),
                     _mask_links(masks.get(i), artifacts), silhouette)
              for i, name in enumerate(record.names)]
    model = ModelRef(id=str(model_id or "unknown"), category=retrieval.get("category"))
    order = [record.names[i] for i in walk_order(retrieval, len(record.names))]
    warnings = _tolerant(folder.read_warnings)
    if warnings is None:  # a job finished before its warnings were written to its folder
        warnings = job_warnings(retrieval, record.names,
                                [w for photo in photos for w in photo.mask_warnings])
    return JobResult(id=record.id, model=model, photos=photos,
                     discarded=[p.name for p in photos if p.discarded], order=order,
                     reordered=bool(retrieval.get("reordered")),
                     metrics=metrics if isinstance(metrics, dict) else {},
                     artifacts=artifacts, warnings=warnings)


