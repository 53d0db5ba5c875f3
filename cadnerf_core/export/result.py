"""The job's result (``jobresult.JobResult``) from what its stages wrote: built once, at the end
of export, and written as ``result.json`` through the job folder."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from cadnerf_core.job_warnings import job_warnings, walk_order
from cadnerf_core.jobfolder import MaskRecord
from cadnerf_core.jobresult import JobMetrics, JobResult, ModelRef, PhotoResult

if TYPE_CHECKING:
    from cadnerf_core.retrieval.result import PhotoMatch, RetrievalResult


def _photo(pose: dict[str, Any], match: PhotoMatch, scores: dict[str, Any],
           mask: MaskRecord | None) -> PhotoResult:
    """One photo's entry: its ``poses.json`` entry (with how its camera was placed and the
    confidence, ``cameras.confidence``), retrieved view, metrics and mask."""
    kept = not pose["discarded"]
    return PhotoResult(
        index=pose["index"], name=pose["name"], discarded=pose["discarded"], iou=pose["iou"],
        view=match.view, azimuth=match.azimuth, elevation=match.elevation,
        c2w=pose["c2w"] if kept else None, c2w_initial=pose["c2w_initial"],
        K=pose["K_photo"] if kept else None, width=pose["width"], height=pose["height"],
        placement=pose.get("placed") if kept else None,
        confidence=pose.get("confidence") if kept else None,
        psnr=scores.get("psnr"), ssim=scores.get("ssim"),
        pose_change_deg=scores.get("pose_change_deg"),
        mask_source=None if mask is None else mask.source,
        mask_warnings=[] if mask is None else list(mask.warnings),
        mask=None if mask is None else mask.mask, overlay=None if mask is None else mask.overlay)


def job_result(retrieval: RetrievalResult, poses: Sequence[dict[str, Any]],
               metrics: dict[str, Any], masks: Sequence[MaskRecord],
               artifacts: Sequence[str]) -> JobResult:
    """A finished job's result; its warnings are those of the cameras training started from
    (``job_warnings``: after the start's choice, which may set the matches aside).

    Args:
        retrieval: the cameras training started from (after the start was chosen).
        poses: ``poses.json``'s entries (``export.artifacts.poses_json``), one per photo.
        metrics: ``metrics.json`` (``export.artifacts.metrics_json``).
        masks: ``masks.json``'s records, one per photo.
        artifacts: the downloadable files' names.
    Returns:
        What ``result.json`` holds.
    """
    by_name = {entry["name"]: entry for entry in metrics.get("photos", [])}
    records = {record.index: record for record in masks}
    matches = {match.index: match for match in retrieval.matches}
    photos = [_photo(pose, matches[pose["index"]], by_name.get(pose["name"], {}),
                     records.get(pose["index"]))
              for pose in poses]
    names = [photo.name for photo in photos]
    warnings = job_warnings(retrieval.to_json(), names,
                            [text for photo in photos for text in photo.mask_warnings])
    summary = {key: value for key, value in metrics.items() if key in JobMetrics.model_fields}
    return JobResult(
        model=ModelRef(id=retrieval.model_id, category=retrieval.category,
                       perspective="near" if retrieval.perspective == "near" else "far"),
        photos=photos, discarded=[p.name for p in photos if p.discarded],
        order=[names[i] for i in walk_order({"order": retrieval.order}, len(names))],
        reordered=retrieval.reordered, metrics=JobMetrics.model_validate(summary),
        warnings=list(warnings), artifacts=list(artifacts))
