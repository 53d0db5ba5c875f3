"""A finished job's ``result.json`` as the pipeline writes it, for tests that fake the pipeline
(the API serves the file; ``tests/e2e`` checks the real pipeline's)."""

from __future__ import annotations

from typing import Any

from cadnerf_core.jobfolder import RESULT, JobFolder
from cadnerf_core.jobresult import JobMetrics, JobResult, ModelRef, PhotoResult

EYE = [[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.2], [0.0, 0.0, 1.0, 3.9], [0.0, 0.0, 0.0, 1.0]]
K = [[50.0, 0.0, 40.0], [0.0, 50.0, 32.0], [0.0, 0.0, 1.0]]


def fake_result(folder: JobFolder, model_id: str = "chair_01", discarded: tuple[int, ...] = (),
                **fields: Any) -> JobResult:
    """A result for the photos in ``folder`` (their masks' records where written), listing the
    artifacts present and ``result.json``; ``fields`` replace the result's own."""
    masks = {record.index: record for record in folder.read_mask_sources()}
    photos = []
    for photo in folder.photos():
        record, kept = masks.get(photo.index), photo.index not in discarded
        photos.append(PhotoResult(
            index=photo.index, name=photo.name, discarded=not kept, iou=0.9 - 0.1 * photo.index,
            view=3 * photo.index, azimuth=18.0 * photo.index, elevation=15.0,
            c2w=EYE if kept else None, c2w_initial=EYE, K=K if kept else None,
            placement="silhouettes" if kept else None,
            mask_source=None if record is None else record.source,
            mask_warnings=[] if record is None else record.warnings,
            mask=None if record is None else record.mask,
            overlay=None if record is None else record.overlay))
    names = [name for name in folder.artifacts() if name != RESULT]
    result = JobResult(model=ModelRef(id=model_id, category=model_id.split("_")[0]),
                       photos=photos, discarded=[p.name for p in photos if p.discarded],
                       order=[p.name for p in photos], metrics=JobMetrics(mean_psnr=21.5),
                       warnings=[w for p in photos for w in p.mask_warnings],
                       artifacts=[*names, RESULT])
    return result.model_copy(update=fields)


def write_fake_result(folder: JobFolder, **fields: Any) -> JobResult:
    """Write ``fake_result(folder, **fields)`` as the folder's ``result.json``; returns it."""
    result = fake_result(folder, **fields)
    folder.write_result(result)
    return result
