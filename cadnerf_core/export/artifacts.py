"""Everything a user downloads, in one pass: views, the orbit, the textured mesh, the files
for other tools (``images/``, ``transforms.json``, ``sparse/0/``), JSON, and ``results.zip``.

Names and places come from ``cadnerf_core.jobfolder``; each kind of file has its own module
here (``renders``, ``media``, ``mesh``, ``texture``, ``bundle``, ``colmap``). Every file is
written atomically (a temporary file beside it, then a rename), so a reader never sees half a
file and a killed job leaves no truncated artifact.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cadnerf_core.cameras.conventions import rotation_angle_deg
from cadnerf_core.export.bundle import (
    CONVENTIONS,
    export_for_tools,
    novel_view_entries,
    write_bundle,
)
from cadnerf_core.export.mesh import EXPORT_STEPS, export_mesh
from cadnerf_core.export.photo_texture import photo_views
from cadnerf_core.export.renders import novel_cameras, render_orbit, render_views
from cadnerf_core.export.result import job_result
from cadnerf_core.jobfolder import RESULT, JobFolder
from cadnerf_core.jobresult import JobResult
from cadnerf_core.progress import Progress

if TYPE_CHECKING:
    from cadnerf_core.nerf.model import TrainedModel
    from cadnerf_core.nerf.state import TrainData
    from cadnerf_core.retrieval.result import RetrievalResult


def poses_json(model: TrainedModel, retrieval: RetrievalResult,
               sizes: dict[int, tuple[int, int]],
               scales: dict[int, float] | None = None) -> list[dict[str, Any]]:
    """Per photo: name, refined and initial c2w, IoU, discarded, how its camera was placed and
    a confidence (``cameras.confidence``; None for a discarded photo), K (crop and photo
    pixels), and the photo's width and height (``sizes``: photo index -> (width, height) as
    uploaded).

    ``scales``: per photo index, uploaded pixels per working pixel (``Photo.scale``), so that
    ``K_photo`` holds for the photo as uploaded; None: 1.
    """
    from cadnerf_core.cameras.confidence import camera_placements
    from cadnerf_core.intake.crop import uncrop_intrinsics

    refined = dict(zip([m.index for m in retrieval.kept], model.c2w, strict=True))
    placed = {p.index: p for p in camera_placements(retrieval.to_json())}
    out = []
    for m in retrieval.matches:
        pose = refined.get(m.index)
        width, height = sizes[m.index]
        how = placed.get(m.index)
        out.append({"name": m.name, "index": m.index, "discarded": m.discarded, "iou": m.iou,
                    "placed": None if how is None else how.placed,
                    "confidence": None if how is None else how.confidence,
                    "c2w": None if pose is None else pose.tolist(),
                    "c2w_initial": m.c2w.tolist(), "library_view": m.view,
                    "K_canonical": m.K_canon.tolist(), "canonical_size": m.box.size,
                    "K_photo": _scaled(uncrop_intrinsics(m.K_canon, m.box),
                                       (scales or {}).get(m.index, 1.0)).tolist(),
                    "width": width, "height": height})
    return out


def _scaled(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics [3, 3] in pixels ``scale`` times larger (focal lengths and principal point)."""
    out = np.array(K, dtype=np.float64)
    out[:2] *= scale
    return out


def metrics_json(model: TrainedModel, retrieval: RetrievalResult,
                 scores: list[dict[str, float]]) -> dict[str, Any]:
    """Training-view PSNR/SSIM per photo, pose change from retrieval, timings, peak memory."""
    kept = retrieval.kept
    init = np.stack([m.c2w for m in kept])
    refined = model.c2w
    rot = rotation_angle_deg(np.swapaxes(init[:, :3, :3], -1, -2) @ refined[:, :3, :3])
    trans = np.linalg.norm(init[:, :3, 3] - refined[:, :3, 3], axis=-1)
    photos = [{"name": m.name, **s, "pose_change_deg": float(r), "pose_change_translation":
               float(t)} for m, s, r, t in zip(kept, scores, rot, trans, strict=True)]
    return {"photos": photos,
            "mean_psnr": float(np.mean([s["psnr"] for s in scores])),
            "mean_ssim": float(np.mean([s["ssim"] for s in scores])),
            "mean_pose_change_deg": float(np.mean(rot)),
            "focal_scale": float(model.extra.get("focal_scale", 1.0)),
            "timings_s": model.extra.get("timings", {}),
            "peak_memory_mb": model.extra.get("memory", {}),
            "resumed_after_phase": model.extra.get("resumed_after_phase", 0),
            "device": str(model.state.device)}


def export_job(job_dir: Path, model: TrainedModel, retrieval: RetrievalResult,
               photos: list[Any], data: TrainData, progress: Progress,
               masks: list[np.ndarray] | None = None) -> JobResult:
    """Write every artifact of a trained job, then its result (``result.json``), and return
    the result.

    Timings of each part land in ``metrics.json`` (``timings_s``: ``views_s``, ``orbit_s``,
    ``mesh_s`` with the texture bake, ``bundle_s``, and their sum ``export_s``).

    Args:
        photos: the job's photos (cadnerf_core.intake.photos.Photo), for their pixel sizes as
            uploaded (working size times ``scale``), and their pixels for the mesh's texture.
        masks: per photo, its object mask [H, W] bool at working size (``Intake.masks``), so
            the texture reads only the object; None: the photos' own (``Photo.mask``).
    """
    import time

    timings = model.extra.setdefault("timings", {})
    start = mark = time.perf_counter()

    def lap(key: str) -> None:
        nonlocal mark
        now = time.perf_counter()
        timings[key], mark = now - mark, now

    ecfg = model.state.config.export
    n_views = data.n_images + ecfg.novel_views
    total = n_views + ecfg.orbit_frames
    views, scores = render_views(job_dir, model, data, progress, total)
    lap("views_s")
    render_orbit(job_dir, model, data, progress, n_views, total)
    lap("orbit_s")
    progress.step("export", 0, EXPORT_STEPS)
    seen_by = photo_views(model, retrieval, photos, masks) if ecfg.texture_from_photos else []
    mesh = export_mesh(job_dir, model, progress, seen_by)
    lap("mesh_s")
    sizes = {i: tuple(p.size) for i, p in enumerate(photos)}
    poses = poses_json(model, retrieval, sizes, {i: float(p.scale) for i, p in enumerate(photos)})
    novel, K_novel = novel_cameras(model, data)
    folder = JobFolder(job_dir)
    progress.check()  # before any output: a cancelled or deleted job writes nothing more
    folder.write_poses(retrieval.model_id, poses, {
        "conventions": CONVENTIONS,
        "novel_views": novel_view_entries(views[data.n_images:], novel, K_novel,
                                          ecfg.orbit_size)})
    export_for_tools(job_dir, poses, model.c2w, mesh)
    progress.step("export", 5, EXPORT_STEPS)
    lap("bundle_s")
    timings["export_s"] = time.perf_counter() - start
    metrics = metrics_json(model, retrieval, scores)
    progress.check()
    folder.write_metrics(metrics)
    result = job_result(retrieval, poses, metrics, folder.read_mask_sources(), [])
    progress.check()
    folder.write_warnings(result.warnings)  # the intake's, now those of the chosen start
    write_bundle(folder)
    artifacts = [name for name in folder.artifacts() if name != RESULT]
    result = result.model_copy(update={"artifacts": [*artifacts, RESULT]})
    progress.check()
    folder.write_result(result)
    progress.step("export", EXPORT_STEPS, EXPORT_STEPS)
    return result
